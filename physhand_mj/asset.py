"""The layered-body asset: arrays in one ``.npz``, loaded and validated at the boundary.

Vertex order is fixed: skin vertices first (``[0, n_skin)``, so skin triangles index them
directly), then flesh (interior tet nodes), then skeleton (bone-surface) vertices. Positions are in
the hand frame (metres) in the rest pose the asset was built in.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from physhand_mj.types import Layer

SCHEMA_VERSION = 1
DEFAULT_ASSET = Path(__file__).parent / "assets" / "myohand_layered.npz"


class AssetError(ValueError):
    """A layered-body asset is missing, corrupted, of another schema version, or inconsistent."""


@dataclass(frozen=True)
class HandAsset:
    """A layered body (skin, flesh, skeleton). Shapes use N vertices, T tets, E edges.

    Attributes:
      positions: (N, 3) float64, rest positions in the hand frame (m).
      layer: (N,) int8, :class:`~physhand_mj.types.Layer` of each vertex.
      skin_faces: (F, 3) int32, outward skin triangles (indices < n_skin).
      tets: (T, 4) int32, positively oriented tetrahedra.
      tet_rest_volume: (T,) float64, rest volumes (m^3), Eq. 3.
      edges: (E, 2) int32, all tet edges; edge_rest_length: (E,) float64 (m), Eq. 2.
      mass: (N,) float64, lumped vertex masses (kg) from the tissue density.
      density: tissue density (kg/m^3).
      attach: (A, 2) int32, (vertex, nearest skeleton vertex) pairs, Eq. 4-5, for every flesh and
        skin vertex; attach_rest_length: (A,) float64 (m).
      dihedral: (D, 4) int32, skin triangle pairs (shared edge e0, e1; opposite o0, o1), Eq. 6;
        dihedral_rest_angle: (D,) float64 (rad), 0 for a flat pair.
      bone_faces: (Fb, 3) int32, outward bone triangles over skeleton vertices.
      body_names: (B,) str, MuJoCo body names; vertex_body: (N,) int32, body index of each skeleton
        vertex (-1 elsewhere).
      body_rest_pos: (B, 3), body_rest_quat: (B, 4): each body's pose in the hand frame at rest
        (MuJoCo quaternion order w, x, y, z).
      rest_qpos_names, rest_qpos: the joint values (rad) of the rest pose.
      meta: free-form build facts (source, licence, parameters, quality figures).
    """

    positions: np.ndarray
    layer: np.ndarray
    skin_faces: np.ndarray
    tets: np.ndarray
    tet_rest_volume: np.ndarray
    edges: np.ndarray
    edge_rest_length: np.ndarray
    mass: np.ndarray
    density: float
    attach: np.ndarray
    attach_rest_length: np.ndarray
    dihedral: np.ndarray
    dihedral_rest_angle: np.ndarray
    bone_faces: np.ndarray
    body_names: np.ndarray
    vertex_body: np.ndarray
    body_rest_pos: np.ndarray
    body_rest_quat: np.ndarray
    rest_qpos_names: np.ndarray
    rest_qpos: np.ndarray
    meta: dict

    @property
    def n_vertices(self) -> int:
        return len(self.positions)

    @property
    def n_skin(self) -> int:
        return int(np.count_nonzero(self.layer == Layer.SKIN))

    def count(self, layer: Layer) -> int:
        return int(np.count_nonzero(self.layer == layer))

    @property
    def skin_vertices(self) -> np.ndarray:
        """(n_skin, 3) rest skin vertices (m)."""
        return self.positions[: self.n_skin]

    def summary(self) -> dict:
        """Counts and quality figures as plain numbers (for logs and docs)."""
        return dict(skin_vertices=self.n_skin, flesh_vertices=self.count(Layer.FLESH),
                    skeleton_vertices=self.count(Layer.SKELETON), skin_triangles=len(self.skin_faces),
                    bone_triangles=len(self.bone_faces), tets=len(self.tets), edges=len(self.edges),
                    bodies=len(self.body_names), **{k: v for k, v in self.meta.items() if k.startswith("q_")})


# name -> (dtype kind, trailing shape); None for scalars
_ARRAYS = {
    "positions": ("f", (3,)), "layer": ("i", ()), "skin_faces": ("i", (3,)), "tets": ("i", (4,)),
    "tet_rest_volume": ("f", ()), "edges": ("i", (2,)), "edge_rest_length": ("f", ()), "mass": ("f", ()),
    "attach": ("i", (2,)), "attach_rest_length": ("f", ()), "dihedral": ("i", (4,)),
    "dihedral_rest_angle": ("f", ()), "bone_faces": ("i", (3,)), "body_names": ("U", ()),
    "vertex_body": ("i", ()), "body_rest_pos": ("f", (3,)), "body_rest_quat": ("f", (4,)),
    "rest_qpos_names": ("U", ()), "rest_qpos": ("f", ()),
}


def save_asset(asset: HandAsset, path: str | Path) -> Path:
    """Write ``asset`` as a compressed ``.npz`` with the schema version."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {f.name: getattr(asset, f.name) for f in fields(asset) if f.name not in ("meta", "density")}
    np.savez_compressed(path, schema_version=np.int64(SCHEMA_VERSION), density=np.float64(asset.density),
                        meta=np.array(json.dumps(asset.meta, sort_keys=True)), **arrays)
    return path


def load_asset(path: str | Path | None = None) -> HandAsset:
    """Load and validate a layered-body asset (the embedded MyoHand by default).

    Raises:
      AssetError: the file is missing or unreadable, of another schema version, or inconsistent;
        the message says what is wrong and how to fix it.
    """
    path = Path(path) if path is not None else DEFAULT_ASSET
    if not path.is_file():
        raise AssetError(f"asset {path} not found; rebuild it with `physhand build-hand --out {path}`")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as e:  # zip/npy corruption surfaces as many exception types
        raise AssetError(f"asset {path} is not a readable .npz ({type(e).__name__}: {e}); "
                         "rebuild it with `physhand build-hand`") from e
    version = int(data.get("schema_version", -1))
    if version != SCHEMA_VERSION:
        raise AssetError(f"asset {path} has schema version {version}, this physhand_mj reads "
                         f"version {SCHEMA_VERSION}; rebuild it with `physhand build-hand`")
    missing = [k for k in [*_ARRAYS, "density", "meta"] if k not in data]
    if missing:
        raise AssetError(f"asset {path} lacks arrays {missing}; rebuild it with `physhand build-hand`")
    try:
        meta = json.loads(str(data["meta"]))
    except json.JSONDecodeError as e:
        raise AssetError(f"asset {path}: its meta record is not JSON ({e})") from e
    asset = HandAsset(density=float(data["density"]), meta=meta, **{k: data[k] for k in _ARRAYS})
    validate_asset(asset, str(path))
    return asset


def validate_asset(a: HandAsset, where: str = "asset") -> None:
    """Check shapes, dtypes, index ranges, finiteness and the physical invariants; raise AssetError."""

    def fail(msg: str):
        raise AssetError(f"{where}: {msg}")

    for name, (kind, trailing) in _ARRAYS.items():
        arr = getattr(a, name)
        if not isinstance(arr, np.ndarray) or arr.dtype.kind not in (kind, "u" if kind == "i" else kind):
            fail(f"array '{name}' should have dtype kind '{kind}', got {getattr(arr, 'dtype', type(arr))}")
        if arr.shape[1:] != trailing:
            fail(f"array '{name}' should have shape (n, {', '.join(map(str, trailing))}), got {arr.shape}")
        if kind == "f" and not np.all(np.isfinite(arr)):
            fail(f"array '{name}' holds non-finite values")
    n = len(a.positions)
    per_vertex = {"layer": a.layer, "mass": a.mass, "vertex_body": a.vertex_body}
    for name, arr in per_vertex.items():
        if len(arr) != n:
            fail(f"'{name}' has {len(arr)} entries for {n} vertices")
    for name, lengths in (("tets", a.tet_rest_volume), ("edges", a.edge_rest_length),
                          ("attach", a.attach_rest_length), ("dihedral", a.dihedral_rest_angle)):
        if len(getattr(a, name)) != len(lengths):
            fail(f"'{name}' and its rest values differ in length")
    for name in ("skin_faces", "tets", "edges", "attach", "dihedral", "bone_faces"):
        idx = getattr(a, name)
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            fail(f"'{name}' indexes vertices outside [0, {n})")
    if not set(np.unique(a.layer)) <= {int(v) for v in Layer}:
        fail(f"'layer' holds labels outside {[int(v) for v in Layer]}")
    if np.any(np.diff(-a.layer.astype(int)) < 0):
        fail("vertices must be ordered skin, flesh, skeleton")
    n_skin = a.n_skin
    if a.skin_faces.size and a.skin_faces.max() >= n_skin:
        fail("skin triangles must use skin vertices only")
    skel = a.layer == Layer.SKELETON
    if np.any(a.vertex_body[skel] < 0) or np.any(a.vertex_body[skel] >= len(a.body_names)):
        fail("every skeleton vertex needs a body index in [0, len(body_names))")
    if np.any(a.vertex_body[~skel] != -1):
        fail("only skeleton vertices may carry a body index")
    if np.any(~skel[a.attach[:, 1]]) or np.any(skel[a.attach[:, 0]]):
        fail("attachments must join a flesh/skin vertex to a skeleton vertex")
    if len(a.body_rest_pos) != len(a.body_names) or len(a.body_rest_quat) != len(a.body_names):
        fail("body rest poses must have one row per body")
    if len(a.rest_qpos) != len(a.rest_qpos_names):
        fail("rest_qpos and rest_qpos_names differ in length")
    if np.any(a.tet_rest_volume <= 0):
        bad = np.flatnonzero(a.tet_rest_volume <= 0)
        fail(f"{len(bad)} tets have non-positive rest volume (degenerate or inverted; first {bad[:5].tolist()}): "
             f"drop degenerate tets and order each tet's vertices for a positive volume (soft_body reorients)")
    _check_skin(a, fail)
    x = a.positions
    t = a.tets
    vol = np.einsum("ij,ij->i", np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]]), x[t[:, 3]] - x[t[:, 0]]) / 6
    if not np.allclose(vol, a.tet_rest_volume, rtol=1e-6, atol=1e-18):
        fail("tet rest volumes do not match the rest positions")
    if np.any(a.edge_rest_length <= 0):
        fail("edges must have positive rest length")
    if np.any(a.mass[~skel] <= 0) or not np.isfinite(a.density) or a.density <= 0:
        fail("flesh and skin vertices need positive mass and the density must be positive")


def _check_skin(a: HandAsset, fail) -> None:
    """The skin surface: no zero-area triangle (its normal and Eq. 6 angle are undefined), no edge
    in more than two triangles (non-manifold), and closed where the body has tets (the inside that
    the object-side contact and the second penetration measure need)."""
    f = a.skin_faces
    if not len(f):
        return
    x = a.positions
    area = 0.5 * np.linalg.norm(np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]), axis=1)
    if np.any(area <= 1e-14):
        bad = np.flatnonzero(area <= 1e-14)
        fail(f"{len(bad)} skin triangles have zero area (first {bad[:5].tolist()}): remove them or merge their "
             f"vertices")
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    if np.any(count > 2):
        fail(f"the skin is non-manifold: {int(np.sum(count > 2))} edges lie in more than two triangles (first "
             f"{edges[count > 2][0].tolist()}): split the surface so each edge joins at most two")
    if len(a.tets) and np.any(count == 1):
        fail(f"the skin of a body with tets must be closed: {int(np.sum(count == 1))} edges lie in one triangle "
             f"only (first {edges[count == 1][0].tolist()}): close its holes (or pass no skin_faces)")
