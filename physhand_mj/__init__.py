"""physhand_mj: a deformable, physiologically layered human hand (PhysHand) for MuJoCo.

Public API (everything else is private):

- :func:`load_asset`, :class:`HandAsset`, :class:`AssetError`, :data:`DEFAULT_ASSET`: the layered
  skin/flesh/skeleton body and its validation.
- :class:`Layer`: vertex layer labels.
- :data:`HAND_XML`, :func:`scene_path`, :func:`open_hand_scene`, :func:`set_skin_vertices`,
  :func:`rest_skin_world`: the hand MJCF and its skin mesh geom.
- :class:`RenderUnavailable`: raised where no OpenGL backend can render offscreen.
"""

from physhand_mj.render import select_gl_backend as _select_gl_backend

_select_gl_backend()  # before anything imports mujoco: MuJoCo reads MUJOCO_GL at import

from physhand_mj.asset import DEFAULT_ASSET, SCHEMA_VERSION, AssetError, HandAsset, load_asset  # noqa: E402
from physhand_mj.hand_mjcf import (  # noqa: E402
    HAND_XML, open_hand_scene, rest_skin_world, scene_path, set_skin_vertices)
from physhand_mj.render import RenderUnavailable  # noqa: E402
from physhand_mj.types import Layer  # noqa: E402

__version__ = "0.1.0"
__all__ = ["DEFAULT_ASSET", "HAND_XML", "SCHEMA_VERSION", "AssetError", "HandAsset", "Layer",
           "RenderUnavailable", "load_asset", "open_hand_scene", "rest_skin_world", "scene_path", "set_skin_vertices"]
