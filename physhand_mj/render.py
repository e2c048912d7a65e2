"""Offscreen pictures with MuJoCo's own renderer, and the choice of its OpenGL backend.

MuJoCo picks its GL backend from ``MUJOCO_GL`` when ``mujoco`` is first imported. Where the user
set nothing, :func:`select_gl_backend` (run when ``physhand_mj`` is imported) picks ``egl`` on a
machine with an NVIDIA GPU and ``osmesa`` (software, ``apt-get install -y libosmesa6``) elsewhere.
If no backend works, :class:`RenderUnavailable` says what to install, in one line.
"""

from __future__ import annotations

import ctypes.util
import os
from pathlib import Path

import numpy as np


class RenderUnavailable(RuntimeError):
    """No OpenGL backend could create an offscreen context."""


_HINT = ("no OpenGL backend for offscreen rendering: on a CPU machine install OSMesa "
         "(apt-get install -y libosmesa6) and set MUJOCO_GL=osmesa; on a GPU machine set MUJOCO_GL=egl")


# where the user's MUJOCO_GL cannot work (no such backend, its library missing): what is wrong; rendering
# is then off (MUJOCO_GL=disable) so that ``import mujoco`` does not fail, and make_renderer says this
_GL_PROBLEM: str | None = None
_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}
_VALID = ("egl", "osmesa", "glfw", "glx", "enable", "enabled", "on", "true", "1", "disable", "disabled", "off",
          "false", "0")


def _loads(name: str) -> bool:
    path = ctypes.util.find_library(name)
    try:
        return path is not None and ctypes.CDLL(path) is not None
    except OSError:
        return False


def select_gl_backend() -> str | None:
    """Set ``MUJOCO_GL`` (and ``PYOPENGL_PLATFORM``) if unset; returns the backend in force. A
    ``MUJOCO_GL`` that cannot work here (an unknown value, or egl / osmesa without its library, which
    would make ``import mujoco`` fail) turns rendering off instead: simulation runs, and a picture
    raises :class:`RenderUnavailable` naming the problem, in one line."""
    global _GL_PROBLEM
    chosen = os.environ.get("MUJOCO_GL", "").lower().strip()
    if chosen:
        if chosen not in _VALID:
            _GL_PROBLEM = f"MUJOCO_GL={chosen} is not a MuJoCo backend (egl, osmesa or glfw)"
        elif chosen in _LIBRARIES and not _loads(_LIBRARIES[chosen]):
            _GL_PROBLEM = f"MUJOCO_GL={chosen}: lib{_LIBRARIES[chosen]} cannot be loaded on this machine"
        if _GL_PROBLEM:
            os.environ["MUJOCO_GL"] = "disable"
        return os.environ["MUJOCO_GL"]
    if os.path.exists("/dev/nvidia0") and ctypes.util.find_library("EGL"):
        backend = "egl"
    elif ctypes.util.find_library("OSMesa"):
        backend = "osmesa"
    elif os.environ.get("DISPLAY"):
        backend = "glfw"
    else:
        return None
    os.environ["MUJOCO_GL"] = backend
    if backend in ("egl", "osmesa"):
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


def make_renderer(model, width: int = 640, height: int = 480):
    """A ``mujoco.Renderer`` or :class:`RenderUnavailable` with the fix in its message."""
    import mujoco

    if _GL_PROBLEM:
        raise RenderUnavailable(f"{_GL_PROBLEM}; {_HINT}")
    width = min(width, model.vis.global_.offwidth)
    height = min(height, model.vis.global_.offheight)
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as e:  # backend libraries missing or no display: one clear line
        raise RenderUnavailable(f"{_HINT} (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset')}: {e})") from e


def look_at_camera(center, distance: float, azimuth: float, elevation: float):
    """A free ``mujoco.MjvCamera`` (degrees for the angles, metres for the distance)."""
    import mujoco

    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = np.asarray(center, dtype=float)
    cam.distance = float(distance)
    cam.azimuth = float(azimuth)
    cam.elevation = float(elevation)
    return cam


def render_png(model, data, path: str | Path, camera=None, width: int = 640, height: int = 480,
               scene_option=None) -> Path:
    """Render one frame of ``(model, data)`` to a PNG file; returns the path."""
    import mujoco

    renderer = make_renderer(model, width, height)
    try:
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera=camera if camera is not None else -1, scene_option=scene_option)
        pixels = renderer.render()
    finally:
        renderer.close()
    return write_png(pixels, path)


def write_png(pixels: np.ndarray, path: str | Path) -> Path:
    """Write an ``(H, W, 3)`` uint8 image as PNG (zlib only, no imaging library needed)."""
    import struct
    import zlib

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w, _ = pixels.shape
    raw = b"".join(b"\x00" + np.ascontiguousarray(pixels[r], dtype=np.uint8).tobytes() for r in range(h))

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload))

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    path.write_bytes(png)
    return path


def mesh_scene_spec(meshes, *, floor: bool = False):
    """An ``MjSpec`` holding static mesh geoms: ``meshes`` is a list of (name, vertices, faces, rgba)."""
    import mujoco

    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth = 1600
    spec.visual.global_.offheight = 1200
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    for name, verts, faces, rgba in meshes:
        mesh = spec.add_mesh(name=name)
        mesh.uservert = np.asarray(verts, dtype=np.float64).reshape(-1).tolist()
        mesh.userface = np.asarray(faces, dtype=np.int32).reshape(-1).tolist()
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        spec.worldbody.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name,
                                rgba=list(rgba), contype=0, conaffinity=0)
    if floor:
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.01], rgba=[0.9, 0.9, 0.9, 1])
    return spec
