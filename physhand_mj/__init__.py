"""physhand_mj: a deformable, physiologically layered human hand (PhysHand) for MuJoCo.

Public API (everything else is private):

- :func:`load_asset`, :class:`HandAsset`, :class:`AssetError`, :data:`DEFAULT_ASSET`: the layered
  skin/flesh/skeleton body and its validation.
- :class:`Layer`: vertex layer labels.
- :data:`HAND_XML`, :func:`scene_path`, :func:`open_hand_scene`, :func:`set_skin_vertices`,
  :func:`rest_skin_world`: the hand MJCF and its skin mesh geom.
- :class:`RenderUnavailable`: raised where no OpenGL backend can render offscreen.
- Solver (paper section 3.2): :class:`Config`, :class:`Scheme`, :class:`NonFinite`, :func:`make_model`,
  :class:`Model`, :class:`State`, :class:`Solver`, :class:`SolverError`; :func:`soft_body` builds a
  layered body from arrays; :func:`body_ids`, :func:`bone_poses_at`, :func:`mount_pose` read bone
  poses from MuJoCo.
- :func:`add_skin`, :class:`SkinAttachment`: the soft skin added to any ``MjSpec`` with the hand's
  bones (the asset's names, MyoSuite's older names, a prefix or a name map).
- :class:`SoftHand`: the soft hand coupled to a MuJoCo model (bones and objects in, deformed skin
  back into the model's mesh, contact report).
"""

from physhand_mj.render import select_gl_backend as _select_gl_backend

_select_gl_backend()  # before anything imports mujoco: MuJoCo reads MUJOCO_GL at import

from physhand_mj.asset import DEFAULT_ASSET, SCHEMA_VERSION, AssetError, HandAsset, load_asset  # noqa: E402
from physhand_mj.attach import SkinAttachment, add_skin  # noqa: E402
from physhand_mj.batch import BatchedHands, replicate_asset  # noqa: E402
from physhand_mj.bodies import soft_body  # noqa: E402
from physhand_mj.coupling import SoftHand  # noqa: E402
from physhand_mj.hand_mjcf import (  # noqa: E402
    HAND_XML, body_ids, bone_poses_at, enable_self_proxies, mount_pose, open_hand_scene, rest_skin_world, scene_path,
    set_proxy_margin, set_skin_vertices)
from physhand_mj.render import RenderUnavailable  # noqa: E402
from physhand_mj.solver import Solver, SolverError, make_model  # noqa: E402
from physhand_mj.types import (Config, Execution, Layer, Model, NonFinite, Placement, Scheme, Settings, State,  # noqa: E402
                               Strategy, Tuning)

try:  # the installed distribution's version (pyproject.toml); a source tree never installed has none
    from importlib.metadata import PackageNotFoundError as _NotInstalled
    from importlib.metadata import version as _dist_version

    __version__ = _dist_version("physhand_mj")
except _NotInstalled:
    __version__ = "0+unknown"
__all__ = ["add_skin", "SkinAttachment", "BatchedHands", "replicate_asset", "DEFAULT_ASSET", "HAND_XML", "SCHEMA_VERSION", "AssetError", "Config", "Execution", "Settings", "Tuning", "HandAsset", "Layer", "Model",
           "NonFinite", "Placement", "RenderUnavailable", "Scheme", "SoftHand", "Solver", "SolverError", "State", "body_ids", "bone_poses_at", "enable_self_proxies", "set_proxy_margin",
           "load_asset", "make_model", "mount_pose", "open_hand_scene", "rest_skin_world", "scene_path",
           "set_skin_vertices", "soft_body", "Strategy"]
