"""Data types of the XPBD solver: the immutable Model and the mutable State; the closed sets
(physhand_mj.enums) and the options (physhand_mj.config) are re-exported here.

Shapes use N vertices, K kinematic (skeleton) vertices, B bone bodies, E edges, T tets, A attachment
pairs, D dihedral pairs (skin triangle pairs). All arrays are Warp arrays on ``Config.device``;
nothing is allocated during a step (``physhand_mj.solver.Solver`` preallocates), so a frame can be
captured as one CUDA graph.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from physhand_mj.config import MAX_STABLE_SUBSTEP, PRESETS, Config, Execution, Settings, Tuning
from physhand_mj.enums import GeomType, Layer, NonFinite, Placement, Scheme, Strategy

__all__ = ["MAX_STABLE_SUBSTEP", "PRESETS", "Config", "Execution", "Settings", "Tuning", "GeomType", "Layer", "NonFinite", "Placement", "Scheme",
           "Strategy", "Model", "State", "SolverError"]


class SolverError(RuntimeError):
    """The solver met a state it cannot continue from (non-finite input or state under RAISE)."""


@dataclass(frozen=True)
class Model:
    """Immutable solver data built from a layered asset by :func:`physhand_mj.solver.make_model`.

    Warp arrays (device ``device``):
      rest_x: (N,) vec3, rest positions (m) in the asset frame; inv_mass: (N,) float, 1/kg (0 on
        the skeleton).
      vertex_body: (N,) int, bone body index of each skeleton vertex, -1 elsewhere;
        body_local: (N,) vec3, skeleton vertices' positions in their body frame (m), 0 elsewhere.
      skin_body: (n_skin,) int, the bone of each skin vertex's nearest skeleton vertex at rest (-1
        without a skeleton); skin_local: (n_skin,) vec3, its rest position in that bone's frame (m):
        the skin carried rigidly by its bones (Config.skin_tether); skin_anchor: (n_skin,) vec3, that
        nearest skeleton vertex (the skin vertex's *anchor*) in the same bone's frame (m): where an
        object holds it, no contact push moves the skin vertex (contact/bones.py).
      edge_ids: (E, 2) int; edge_rest: (E,) float (m; negative: a stretch-only edge of that length,
        Config.skin_compression / flesh_compression False); edge_alpha: (E,) float (m/N). The edge family holds the tet
        edges (Eq. 2) and the flesh attachments (Eq. 4, an edge constraint); edge_is_att: (E,) numpy
        bool marks the attachments.
      tet_ids: (T, 4) int; tet_rest6v: (T,) float, 6 x rest volume (m^3); tet_alpha: (T,) float.
      dih_ids: (D, 4) int (e0, e1, o0, o1); dih_rest: (D,) float, signed rest angle (rad);
        dih_alpha: float.
      skin_faces: (F, 3) int.
      vertex_count: (G, N) float, per Jacobi group (solver.model.JACOBI_GROUPS) the number of its
        constraints touching each movable vertex (Jacobi averaging).
      vertex_world: (N,) int, the world of each vertex (batched worlds, physhand_mj/batch.py: the
        asset replicated ``worlds`` times; all 0 for one hand).
      gather_off / gather_slot: per Jacobi group, (N + 1,) int CSR offsets and the slot ids of each
        movable vertex's corrections (``Config.execution.jacobi_gather``, solver/gather.py; empty lists on the
        atomic path); slot_base: per family, its slots' offset within its group; n_slots: the
        largest group's slot count (``State.corr``'s length).
    Host data: ``colors``: per family, the [start, end) ranges of its colours when the scheme is
    COLORED (constraints are stored sorted by colour), a single range otherwise.
    """

    device: str
    n_vertices: int
    n_skin: int
    n_bodies: int
    body_names: tuple
    rest_x: object
    inv_mass: object
    vertex_body: object
    body_local: object
    skin_body: object
    skin_local: object
    skin_anchor: object
    vertex_carrier: object
    edge_ids: object
    edge_rest: object
    edge_alpha: object
    edge_is_att: np.ndarray
    tet_ids: object
    tet_rest6v: object
    tet_alpha: object
    dih_ids: object
    dih_rest: object
    dih_alpha: float
    skin_faces: object
    guard_tets: object
    vertex_count: object
    colors: dict = field(default_factory=dict)
    body_rest_pos: np.ndarray | None = None
    body_rest_quat: np.ndarray | None = None
    vertex_world: object = None
    worlds: int = 1
    gather_off: list = field(default_factory=list)
    gather_slot: list = field(default_factory=list)
    slot_base: dict = field(default_factory=dict)
    n_slots: int = 0


@dataclass
class State:
    """Mutable solver state (all preallocated by ``Solver.make_state``).

    x: (N,) vec3 positions (m); v: (N,) vec3 velocities (m/s); x_prev: (N,) vec3 positions at the
    start of the substep (Algorithm 1, x^i); x_safe: (N,) vec3 positions at the end of the last frame
(the non-finite guard's fallback); delta: (N,) vec3 Jacobi correction accumulator; corr:
    (Model.n_slots,) vec3, the constraints' own correction slots when the solver gathers
    (Config.execution.jacobi_gather, solver/gather.py; empty otherwise);
    lam_edge/lam_tet/lam_dih: Lagrange multipliers per constraint (Algorithm 1, line 11);
    body_pose: (2, B) transforms of the bones at the start / end of the frame (uploaded each frame
    from pose_host, (2, B, 7) float32 numpy: position, quaternion x y z w);
    body_sub: (substeps, B) their interpolated poses at the end of each substep;
    guard: (4,) int counters [non-finite vertices, inverted tets, skin vertices the tether held
    (summed over substeps), soft vertices ending the frame faster than Config.sleep_speed] of the
    last frame; with batched worlds (Model.worlds W > 1) (4 + 4 W,): then the same four per world
    (world w at [4 + 4 w, 8 + 4 w)); time: s.
    """

    x: object
    v: object
    x_prev: object
    x_safe: object
    delta: object
    lam_edge: object
    lam_tet: object
    lam_dih: object
    body_pose: object
    body_sub: object
    guard: object
    pose_host: np.ndarray = None
    pose_fresh: bool = False
    time: float = 0.0
    frames: int = 0
    still: int = 0  # frames in a row that ended settled (the sleep test, activity.py)
    sleep_onset: object = None  # asleep: (bone poses (B, 7) when it fell asleep, first bone's velocity m/s)
    sleep_box: object = None  # asleep on CUDA: the sleeping skin's box corners in the first bone's frame (8, 3) m
    corr: object = None  # the constraints' correction slots (Config.execution.jacobi_gather); set by Solver.make_state
