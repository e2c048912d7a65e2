"""The options: what a user chooses (:class:`Config`), the contact algorithm's measured constants
(:class:`Tuning`), the kernel choices the code makes (:class:`Execution`), and the validated, flat
:class:`Settings` the solver runs on (``Config.validate()``). Re-exported by :mod:`physhand_mj.types`.

A user sets :class:`Config` fields (SI units; the table in docs/config.md). :class:`Tuning` holds the
contact's and solver's constants whose defaults the project measured (docs/contact.md says why each
is what it is); change them to reproduce an experiment, not to fix a scene. :class:`Execution`
holds choices of kernels, launches and caches that never change a result beyond float rounding; the
code chooses them (``None``: decide per device and batch) and tests and benchmarks force them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from physhand_mj.enums import NonFinite, Placement, Scheme, Strategy, enum_field

MAX_STABLE_SUBSTEP = 2.0e-3  # s: longer substeps collapse the flesh (tests/stress/test_stress_fast.py: 5 and 10 ms do)

# A feature point is listed for a contact stage when it lies within contact_margin + this share of
# Tuning.feature_slack of the skin (0.5: the frame's check certifies the list under the bound on the
# skin's move that the patches need anyway; 1, the lists before 2026-11-27, left half of the box's
# points where no pass could push them in time: CHANGELOG.md).
FEATURE_LIST_SHARE = 0.5


@dataclass
class Tuning:
    """The algorithm's constants, each default measured (docs/contact.md, docs/solver.md).

    Solver:
      scheme: :class:`Scheme` (JACOBI: every constraint of a family at once, corrections averaged;
        COLORED: Gauss-Seidel over graph colours); relaxation: Jacobi over-relaxation (1: plain mean).
      edges, volumes, attachment, smoothness: switch a constraint family off (the paper's Fig. 6
        ablation); attach_skin: also attach skin vertices to their nearest skeleton vertex.
    Contact (skin side, the decision points of Algorithm 2 and Eq. 9):
      contact_placement: :class:`Placement` of the contact stage in a substep (AFTER the constraints).
      contact_margin: the stage broadphase's margin (m; how far one stage's corrections drag a
        triangle that did not penetrate itself).
      contact_offset: how far outside an object Eq. 9 puts a decision point (m; 20 um: float32
        rounding, a faceted mesh's missed minimum (~3.5 um on the HOI bowl) and the order-5 lattice's
        misses between its samples at convex edges and lying rods, 1-5 um; docs/contact.md).
      contact_pass_tol: in every stage but the frame's last, a pass runs only when the one before it
        moved a vertex by more than this (m; 0: until a pass moves nothing).
      multires_samples / multires_rounds: Algorithm 2's samples per round and rounds (21 x 2: an
        order-5 first round catches the narrow penetrations at sharp rims that 16 x 2 misses).
      opt_queries: Frank-Wolfe queries of the OPT strategy (the paper's baseline: 32).
      side_aware: where the SDF gradient at a decision point points out of the hand, leave the object
        along the triangle's inward normal instead of by Eq. 9 (deep starts, thin walls).
      bone_hold: where an object holds the bone under a skin vertex (its nearest skeleton vertex at
        rest), no contact push moves that vertex: no penetration-free skin exists there
        (contact/bones.py; the contact report names the bone and its depth).
      flesh_carry: the share (0 to 1; 0, the default: off) of a contact stage's move of the skin that
        the flesh right under it takes in the same stage (each movable flesh vertex sharing a tet
        with skin: that share of its skin neighbours' mean move), so deep pushes do not shear the
        skin layer's tets inside out (solver/carry.py; 0.5 measured: docs/contact.md).
      wall_carry: the same share (0 to 1; 0.5, the default) for the skin within the frame margin of
        a broad wall (a plate or a shell at most 1.5 mm half-thick: contact/inside.py
        ``wall_half_thickness``, ``wall_is_broad``), where the skin is dragged across the wall's face
        and the flesh left behind pulls it back over the rims (docs/contact.md "Thin walls"); a scene
        without one runs nothing for it. The larger of the two shares applies.
      touch_damping: after each contact stage the velocity of every skin vertex an object pushed in
        the frame decays over this time (s; 7.2e-4, the default, halves it every stage at 10
        substeps; 0: off), so held contact comes to rest instead of swinging at thin walls' rims and
        star points (contact/touch.py; docs/contact.md "Held contact at rest"). Only the motion
        relative to the vertex's carrier bone is damped (skin riding a moving finger is not held
        back); with two_way, contact_damping acts instead.
    Contact (object side, the features: corners, tips and sharp edges smaller than a triangle):
      feature_offset: how far outside the skin a pushed feature point ends (m; 60 um; 80 um and more
        let a 1 mm plate tunnel); feature_last_offset: the stage's last push's (m; None: feature_offset);
      feature_spacing: feature points along sharp edges, apart (m; 0.25 mm);
      feature_slack: the least skin motion within a frame that the feature lists and patches are
        sized for (m; 4 mm); it follows 2.5 x the skin's largest move near the points, up to
        ``Config.contact_frame_margin``; a frame that moved more is reported
        (``feature_slack_exceeded``) and the next frame's slack grows;
      feature_winding: decide inside/outside by the local winding number, not the pseudo normals alone;
      feature_last: end every stage with one more feature push after its last Eq. 9.
    Sleeping: sleep_frames: calm frames before the hand (or a region) sleeps (count);
      sleep_bone_motion: a bone's motion relative to the first bone that counts as still (m a frame).
    Self-collision (``Config.self_collision``; docs/self_collision.md):
      self_thickness: how far in front of another part's skin triangle a skin vertex is kept (m);
      self_margin: the frame's list holds the skin triangles within this of a vertex at the frame's
        start (m; how far two parts may approach each other in one frame);
      self_rest_gap: the rest filter: a vertex and a triangle nearer than this at rest are never a
        pair (m; webs, creases, the surface around the vertex);
      self_depth: a vertex deeper than this behind its nearest triangle is left alone (m; past it the
        nearest triangle is no longer the side it came in through);
      self_passes: correction passes per substep (count);
      self_tet_keep: 0 (default): the hard correction; above 0, a correction is cut short where it
        would flatten a tet of a moved skin vertex below this share of its rest volume (fewer
        inverted tets where the bones leave the flesh no room, more skin left inside; 0 to 1);
      self_friction: Coulomb friction between touching parts of the skin (coefficient, 0 to 2; 0: none):
        a pair's slip along the triangle within a substep is undone up to this times the pair's
        normal correction in each pass.
      self_proxies: SoftHand also turns on the hand model's self proxies (the collision proxies'
        copies of MJCF class ``self_proxy``, which collide only with each other): MuJoCo then keeps
        two parts' bones from coming nearer than where their rest skins would meet, instead of
        squeezing the flesh between them past what any skin can take (True; a model without them:
        nothing to turn on).
      self_edges: also edge-edge pairs: two skin edges within ``self_margin`` at the frame's start
        are kept ``self_thickness`` apart on the side they lie on (False; where the vertex-triangle
        pairs cannot see an edge dive through a triangle past its rim: the knuckles' pleats, the
        grasps' pinched skin. The substep passes then run as launches, never inside the fused
        kernel; docs/self_collision.md "Edge-edge contact").
      self_every: frames one self-contact list serves (count; 1, the default: a query every frame).
        Above 1 the once-a-frame work (the query slack, the refit, the query) runs every
        ``self_every``-th frame and the substeps of the frames between press the pairs it listed:
        that work's cost over ``self_every``, but ``self_margin`` then bounds how far two parts
        approach each other in ``self_every`` frames, not one (a wider margin to match did worse; 2
        kept the option's accuracy where MuJoCo closes the hand: docs/self_collision.md "A list for
        several frames").
      proxy_margin: MuJoCo contact margin SoftHand gives the hand's collision proxies against objects
        (m; geoms ``*_proxy`` of the shipped hand), so MuJoCo stops a bone that much before its proxy
        meets an object. None (default): 2.5 mm (hand_mjcf.PROXY_INSET: about where the rest skin
        over the proxy would touch) with one-way coupling, where nothing else keeps a closing bone
        from crushing the flesh past flat; 0 (the shipped proxies' own) with ``two_way``, where the
        skin's push on the bones does. A number (0 to 0.02 m): that margin either way.
    """

    scheme: Scheme = Scheme.JACOBI
    relaxation: float = 1.0
    edges: bool = True
    volumes: bool = True
    attachment: bool = True
    smoothness: bool = True
    attach_skin: bool = False
    contact_placement: Placement = Placement.AFTER
    contact_margin: float = 5.0e-4
    contact_offset: float = 2.0e-5
    contact_pass_tol: float = 0.0
    multires_samples: int = 21
    multires_rounds: int = 2
    opt_queries: int = 32
    side_aware: bool = True
    bone_hold: bool = True
    flesh_carry: float = 0.0
    wall_carry: float = 0.5
    touch_damping: float = 7.2e-4
    feature_offset: float = 6.0e-5
    feature_last_offset: float | None = None
    feature_spacing: float = 2.5e-4
    feature_slack: float = 4.0e-3
    feature_winding: bool = True
    feature_last: bool = True
    sleep_frames: int = 10
    sleep_bone_motion: float = 1.0e-5
    self_thickness: float = 5.0e-4
    self_margin: float = 2.0e-3
    self_rest_gap: float = 4.0e-3
    self_depth: float = 5.0e-3
    self_passes: int = 4
    self_tet_keep: float = 0.0
    self_friction: float = 0.0
    self_proxies: bool = True
    self_edges: bool = False
    self_every: int = 1
    proxy_margin: float | None = None


@dataclass
class Execution:
    """Kernel, launch and cache choices: results equal up to float rounding (bit for bit on the CPU
    unless said). ``None``: the code decides per device and batch (docs/solver.md, docs/scale.md).

      cuda_graph: capture a frame as one CUDA graph.
      skip_idle: run contact work only when an object is within ``contact_frame_margin`` of the skin.
      reuse_outside: the object-side measure re-asks only points whose answer could have changed.
      mesh_grid: node spacing of each mesh object's distance grid (m; 0: none), a lower bound that
        spares BVH walks where it proves a point far.
      jacobi_gather: Jacobi corrections summed per vertex in a fixed order instead of float atomics
        (None: CUDA batches that do not take the fused substep).
      fused_substep: a substep's constraint groups in one launch, a block per world in shared memory
        (None: the CPU where it fits; CUDA batches of at least 0.3 worlds per SM).
      tiled_contact: CUDA multires with a block of 32 lanes per triangle (None: one hand).
      multires_registers: CUDA batches' multires kernel capped at N registers a thread (0: the
        generic kernel; None: 128 with a mesh object, else 0); multires_block_dim: its block.
      tiled_features: CUDA feature kernels with a block per feature point (None: up to 63 worlds).
    """

    cuda_graph: bool = True
    skip_idle: bool = True
    reuse_outside: bool = True
    mesh_grid: float = 2.0e-3
    jacobi_gather: bool | None = None
    fused_substep: bool | None = None
    tiled_contact: bool | None = None
    multires_registers: int | None = None
    multires_block_dim: int = 256
    tiled_features: bool | None = None


@dataclass
class Config:
    """What a user chooses. SI units; compliance ``alpha = 1/k`` for an energy ``U = C^2 / (2 alpha)``
    of the paper's constraint function ``C``. ``validate()`` returns the flat, checked
    :class:`Settings` a solver runs on; it never changes the Config.

    Device and time:
      device: Warp device, ``"cpu"`` or ``"cuda"`` / ``"cuda:0"``; None: Warp's default.
      frame_dt: simulated time per ``step`` (s; MuJoCo scenes: 0.005).
      substeps: substeps per frame (Algorithm 1: ``h = frame_dt / substeps``).
      max_substep: the longest substep run (s; 2 ms): ``validate()`` raises ``substeps`` where
        ``frame_dt / substeps`` is longer, since the flesh sags and inverts at 5-10 ms substeps
        (docs/stability.md); None keeps ``substeps`` and warns.
      iterations: constraint passes per substep (Algorithm 1 lines 7-13; the paper: 1).
    Physics:
      gravity: (3,) m/s^2 in the solver's world frame; damping: velocity damping rate (1/s).
      edge_compliance_skin / edge_compliance_flesh: Eq. 2 (m/N), skin-skin edges / the others.
      skin_compression: whether skin-skin edges resist compression as well as stretch (True: Eq. 2
        both ways, the paper's). False: stretch only; compressed skin shortens in its plane, as skin
        does by wrinkling finer than the mesh, instead of buckling into millimetre folds that pass
        through the skin beside them (with self_collision the grasps' remaining self-intersections
        drop 2-6 x: docs/self_collision.md "Skin that gives in compression").
      flesh_compression: the same for the flesh's (tet) edges (True: Eq. 2 both ways). False: their
        compression is held by the tets' volumes (Eq. 3) alone, so squeezed flesh bulges more freely
        (with self_collision and skin_compression False the HOI grasps end without a skin edge
        through the skin, and fewer tets invert; the flesh attachments, Eq. 4, resist both ways).
      volume_compliance: Eq. 3 per unit volume (1/Pa: inverse bulk modulus).
      attach_compliance: Eq. 4-5 (m/N); smooth_compliance: Eq. 6 (1/(N m)).
      nonfinite: :class:`NonFinite`: RECOVER (reset the vertex, report it) or RAISE.
    Contact:
      contact: :class:`Strategy` of the decision points (NONE, VERTEX, OPT, MULTIRES: the paper's).
      contact_passes: query + projection rounds per stage, at most (a pass re-tests only what moved).
      contact_every: a contact stage every this many substeps (count; always in the frame's last;
        1: the paper's Algorithm 1). 2 with contact_linear is zero on every hand workload of the
        accuracy sweep at 10 substeps at ~0.87 x the frame, but not on the project's own stress
        presses, nor equal between batched and serial worlds (docs/accuracy.md, "The default contact").
      contact_linear: with contact_every > 1, hold the skin between stages on the planes and feature
        points the last stage found (8-26 % faster than a stage every substep, docs/activity.md;
        without it a stage every second substep leaves residue).
      contact_frame_margin: how far skin and objects may approach each other in one frame (m; 1 cm at
        5 ms frames is 2 m/s); objects farther cost nothing.
      feature_contact: also push the skin off object corners, tips and sharp edges inside it.
      skin_tether: the farthest a skin vertex may be from where its bone carries it (m; 0: off).
      two_way: the skin acts back on the scene (experimental): its contact impulses and Coulomb
        friction act on the objects, free ones moved within the frame at the substep rate, and the
        reaction on the bones; SoftHand hands the objects' poses and everyone's velocity change to
        MuJoCo (contact/exchange.py, docs/coupling.md; BatchedHands per world through
        ``batch.BatchTwoWay``; ``frame_dt`` must equal MuJoCo's timestep).
      contact_damping: with two_way, the flesh's damping at contacts (s): a touching object's normal
        velocity relative to the bones under the skin decays over this time (the flesh's own
        velocity damping leaves a box on the skin ringing for seconds); 0: none.
    Measurement:
      frame_metrics: the skin measure (samples inside objects) at every frame's end.
      substep_metrics: the same after every substep (logs).
      object_metrics: the object measure (object points inside the skin) at every frame's end;
        otherwise ``metrics()`` / ``penetration()`` evaluate it when called.
    Sleeping:
      sleep_speed: the hand sleeps after calm frames with no soft vertex faster than this (m/s; 0:
        never); asleep, a frame is one launch and the skin rides its bones.
      region_sleep: the palm, the thumb and each finger sleep alone (one world).
    Self-collision (opt-in; one hand or batched worlds, not region_sleep; docs/self_collision.md):
      self_collision: keep one part of the hand's skin out of another's (fingers, thumb, palm):
        vertex-triangle contact found once a frame, resolved every substep (Tuning's ``self_*``).
    Expert groups: tuning (:class:`Tuning`), execution (:class:`Execution`).
    """

    device: str | None = None
    frame_dt: float = 0.005
    substeps: int = 10
    max_substep: float | None = 2.0e-3
    iterations: int = 1
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    damping: float = 2.0
    edge_compliance_skin: float = 1.0e-3
    edge_compliance_flesh: float = 1.0e-2
    skin_compression: bool = True
    flesh_compression: bool = True
    volume_compliance: float = 1.0e-6
    attach_compliance: float = 1.0e-3
    smooth_compliance: float = 10.0
    nonfinite: NonFinite = NonFinite.RECOVER
    contact: Strategy = Strategy.MULTIRES
    contact_passes: int = 8
    contact_every: int = 1
    contact_linear: bool = False
    contact_frame_margin: float = 1.0e-2
    feature_contact: bool = True
    skin_tether: float = 0.025
    two_way: bool = False
    contact_damping: float = 0.01
    frame_metrics: bool = True
    substep_metrics: bool = False
    object_metrics: bool = False
    sleep_speed: float = 3.0e-3
    region_sleep: bool = False
    self_collision: bool = False
    tuning: Tuning = field(default_factory=Tuning)
    execution: Execution = field(default_factory=Execution)

    def validate(self) -> "Settings":
        """The checked, flat :class:`Settings` of this Config (ValueError naming the option to fix)."""
        if not isinstance(self.tuning, Tuning):
            raise ValueError(f"Config.tuning must be a physhand_mj.Tuning, got {type(self.tuning).__name__}")
        if not isinstance(self.execution, Execution):
            raise ValueError(f"Config.execution must be a physhand_mj.Execution, got {type(self.execution).__name__}")
        flat = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("tuning", "execution")}
        flat.update(dataclasses.asdict(self.tuning), **dataclasses.asdict(self.execution))
        return Settings(**flat)

    @property
    def substep_dt(self) -> float:
        """h = frame_dt / substeps (s), after ``validate()``'s limit on it."""
        return self.validate().substep_dt

    @classmethod
    def from_dict(cls, options: dict) -> "Config":
        """A Config from a dict of options, as JSON files and scripts write them: each key a Config,
        :class:`Tuning` or :class:`Execution` field (flat), or ``"tuning"`` / ``"execution"`` holding
        a dict or an instance of the group. An unknown key raises ValueError naming it."""
        own, groups = {}, {"tuning": {}, "execution": {}}
        for key, value in dict(options).items():
            if key in ("tuning", "execution"):
                groups[key].update(dataclasses.asdict(value) if dataclasses.is_dataclass(value) else dict(value))
            elif key in _TUNING:
                groups["tuning"][key] = value
            elif key in _EXECUTION:
                groups["execution"][key] = value
            elif key in _OWN:
                own[key] = value
            else:
                raise ValueError(f"unknown Config option {key!r}: see docs/config.md for the options")
        return cls(**own, tuning=Tuning(**groups["tuning"]), execution=Execution(**groups["execution"]))

    @classmethod
    def preset(cls, name: str, **overrides) -> "Config":
        """A named setting of the accuracy sweep's recommendation table (docs/accuracy.md), with
        ``overrides`` on top: ``"default"`` (= ``Config()``), ``"interactive"`` (5 substeps: 0.59 x
        the frame on the CPU sweep, 0.64 x on the H200's, the flesh ~2.5-3 x softer under gravity,
        held presses at the palm 1.5-6 x deeper), ``"dataset"`` (OPT decision points: zero by every
        measure on every hand workload of the sweep on both devices) and ``"robot_pads"`` (OPT at
        5 substeps: zero on every hand workload of the sweep on both devices at 0.59 x the CPU
        frame, with the softer flesh). The presets name a stage every substep
        (``contact_every=1``) themselves."""
        if name not in PRESETS:
            raise ValueError(f"unknown Config preset {name!r}: choose one of {sorted(PRESETS)}")
        config = cls.from_dict({**PRESETS[name], **overrides})
        config.validate()
        return config


_TUNING = {f.name for f in dataclasses.fields(Tuning)}
_EXECUTION = {f.name for f in dataclasses.fields(Execution)}
_OWN = {f.name for f in dataclasses.fields(Config)} - {"tuning", "execution"}


def _settings_fields():
    own = [f for f in dataclasses.fields(Config) if f.name not in ("tuning", "execution")]
    out = []
    for f in own + list(dataclasses.fields(Tuning)) + list(dataclasses.fields(Execution)):
        default = f.default if f.default is not dataclasses.MISSING else dataclasses.MISSING
        out.append((f.name, f.type, field(default=default)))
    # set by validate where it raised substeps to honour max_substep: the count asked for
    out.append(("substeps_requested", "int | None", field(default=None)))
    return out


def _qual(name: str) -> str:
    """The option's name as a user writes it: ``Config.x``, ``Config.tuning.x`` or ``Config.execution.x``."""
    group = "tuning." if name in _TUNING else "execution." if name in _EXECUTION else ""
    return f"Config.{group}{name}"


def _check(s) -> None:
    """Raise ValueError naming the option to fix; normalise enums and the substep count in place
    (on the new Settings only)."""
    def put(name, value):
        object.__setattr__(s, name, value)

    def pos(name):
        v = getattr(s, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{_qual(name)} must be a finite number > 0, got {v!r}")

    def nonneg(name):
        v = getattr(s, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{_qual(name)} must be a finite number >= 0, got {v!r}")

    def flag(name, none_ok=False, hint=""):
        v = getattr(s, name)
        if not ((none_ok and v is None) or isinstance(v, (bool, np.bool_))):
            raise ValueError(f"{_qual(name)} must be {'None' + hint + ', ' if none_ok else ''}True or False, got {v!r}")

    pos("frame_dt")
    for name in ("substeps", "iterations", "contact_passes", "contact_every", "multires_rounds", "opt_queries"):
        v = getattr(s, name)
        if not (isinstance(v, (int, np.integer)) and v >= 1):
            raise ValueError(f"{_qual(name)} must be an integer >= 1, got {v!r}")
    g = np.asarray(s.gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ValueError(f"Config.gravity must be 3 finite numbers (m/s^2), got {s.gravity!r}")
    for name in ("damping", "edge_compliance_skin", "edge_compliance_flesh", "volume_compliance",
                 "attach_compliance", "smooth_compliance"):
        nonneg(name)
    if not (0.0 < s.relaxation < 2.0):
        raise ValueError(f"Config.tuning.relaxation must lie in (0, 2), got {s.relaxation!r}")
    flag("tiled_contact", True, " (one hand: tiled)")
    r = s.multires_registers
    if r is not None and not (isinstance(r, (int, np.integer)) and not isinstance(r, bool)
                              and (r == 0 or 32 <= r <= 255)):
        raise ValueError(f"Config.execution.multires_registers must be None (chosen per run), 0 (the generic kernel) or an "
                         f"integer from 32 to 255 (registers a thread), got {r!r}")
    b = s.multires_block_dim
    if not (isinstance(b, (int, np.integer)) and not isinstance(b, bool) and 32 <= b <= 1024 and b % 32 == 0):
        raise ValueError(f"Config.execution.multires_block_dim must be a multiple of 32 from 32 to 1024 (threads a block), "
                         f"got {b!r}")
    flag("region_sleep")
    flag("self_collision")
    flag("self_proxies")
    flag("self_edges")
    if s.self_edges and not s.self_collision:
        raise ValueError("Config.tuning.self_edges adds edge-edge pairs to Config.self_collision: set self_collision=True "
                         "too (or self_edges=False)")
    m = s.proxy_margin
    if m is not None and not (isinstance(m, (int, float, np.integer, np.floating)) and not isinstance(m, bool)
                              and math.isfinite(m) and 0.0 <= m <= 0.02):
        raise ValueError(f"Config.tuning.proxy_margin must be None (2.5 mm one-way, 0 two-way) or a margin in m "
                         f"from 0 to 0.02 (the proxies sit 0.0025 m inside the rest skin), got {m!r}")
    flag("skin_compression")
    flag("flesh_compression")
    for name in ("self_thickness", "self_margin", "self_rest_gap", "self_depth"):
        pos(name)
    if not (isinstance(s.self_passes, (int, np.integer)) and not isinstance(s.self_passes, bool) and s.self_passes >= 1):
        raise ValueError(f"Config.tuning.self_passes must be an integer >= 1, got {s.self_passes!r}")
    if not (isinstance(s.self_every, (int, np.integer)) and not isinstance(s.self_every, bool) and s.self_every >= 1):
        raise ValueError(f"Config.tuning.self_every must be an integer >= 1 (frames one self-contact list serves), got "
                         f"{s.self_every!r}")
    if not (np.isfinite(s.self_friction) and 0.0 <= s.self_friction <= 2.0):
        raise ValueError(f"Config.tuning.self_friction must be a coefficient in [0, 2] (skin on skin: ~0.5), got "
                         f"{s.self_friction!r}")
    if not (np.isfinite(s.flesh_carry) and 0.0 <= s.flesh_carry <= 1.0):
        raise ValueError(f"Config.tuning.flesh_carry must be a share in [0, 1] (0: off; 0.5 measured), got {s.flesh_carry!r}")
    if not (np.isfinite(s.wall_carry) and 0.0 <= s.wall_carry <= 1.0):
        raise ValueError(f"Config.tuning.wall_carry must be a share in [0, 1] (0: off; 0.5, the default), got {s.wall_carry!r}")
    if not (0.0 <= s.self_tet_keep < 1.0):
        raise ValueError(f"Config.tuning.self_tet_keep must lie in [0, 1), got {s.self_tet_keep!r}")
    if s.self_collision and s.self_margin <= s.self_thickness:
        raise ValueError(f"Config.tuning.self_margin ({s.self_margin} m) must exceed Config.tuning.self_thickness "
                         f"({s.self_thickness} m)")
    if s.self_collision and s.region_sleep:
        raise ValueError("Config.self_collision does not run with Config.region_sleep (a region asleep would skip "
                         "the skin it presses on)")
    flag("fused_substep", True, " (the CPU's and large CUDA batches' default)")
    flag("contact_linear")
    flag("two_way")
    flag("tiled_features", True, " (blocks for one hand, a thread per feature for batches)")
    flag("reuse_outside")
    flag("jacobi_gather", True, " (on CUDA)")
    if not (isinstance(s.multires_samples, (int, np.integer)) and s.multires_samples >= 3):
        raise ValueError(f"Config.tuning.multires_samples must be an integer >= 3, got {s.multires_samples!r}")
    for name in ("contact_margin", "contact_pass_tol", "skin_tether", "contact_frame_margin", "contact_offset", "contact_damping",
                 "touch_damping", "feature_offset", "mesh_grid", "sleep_speed", "sleep_bone_motion"):
        nonneg(name)
    v = s.feature_last_offset
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0):
        raise ValueError(f"Config.tuning.feature_last_offset must be None (feature_offset's stand-off) or a distance "
                         f">= 0 in m (e.g. 6e-6), got {v!r}")
    for name, example in (("feature_slack", "4e-3"), ("feature_spacing", "2.5e-4")):
        v = getattr(s, name)
        if not (isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
                and math.isfinite(v) and v > 0):
            raise ValueError(f"{_qual(name)} must be a distance > 0 in m (e.g. {example}), got {v!r}")
    if not (isinstance(s.sleep_frames, int) and s.sleep_frames >= 1):
        raise ValueError(f"Config.tuning.sleep_frames must be an integer >= 1, got {s.sleep_frames!r}")
    if s.contact_frame_margin < s.contact_margin:
        raise ValueError(f"Config.contact_frame_margin ({s.contact_frame_margin} m) must be at least "
                         f"Config.tuning.contact_margin ({s.contact_margin} m)")
    if s.max_substep is not None:
        ms = s.max_substep
        if isinstance(ms, bool) or not isinstance(ms, (int, float, np.floating, np.integer)) or not (
                math.isfinite(ms) and ms > 0):
            raise ValueError(f"Config.max_substep must be None or a finite number of seconds > 0 (e.g. 0.002), "
                             f"got {ms!r}")
        if s.frame_dt / s.substeps > ms * (1 + 1e-9):
            if s.substeps_requested is None:
                put("substeps_requested", int(s.substeps))
            put("substeps", int(math.ceil(s.frame_dt / ms - 1e-9)))
    elif s.frame_dt / s.substeps > MAX_STABLE_SUBSTEP * (1 + 1e-9):
        from physhand_mj.warn import warn_user

        need = math.ceil(s.frame_dt / MAX_STABLE_SUBSTEP - 1e-9)
        warn_user(f"Config: substeps of {s.frame_dt / s.substeps * 1e3:.3g} ms (frame_dt {s.frame_dt} s / "
                  f"substeps {s.substeps}) are longer than {MAX_STABLE_SUBSTEP * 1e3:g} ms: the flesh sags "
                  f"and inverts under gravity alone and does not recover (docs/stability.md); use substeps "
                  f">= {need} (or leave Config.max_substep at its default, which does)")
    put("contact", enum_field(Strategy, s.contact, "contact"))
    put("contact_placement", enum_field(Placement, s.contact_placement, "tuning.contact_placement"))
    put("scheme", enum_field(Scheme, s.scheme, "tuning.scheme"))
    put("nonfinite", enum_field(NonFinite, s.nonfinite, "nonfinite"))
    if s.fused_substep and (s.scheme != Scheme.JACOBI or s.iterations != 1 or s.region_sleep):
        raise ValueError("Config.execution.fused_substep needs tuning.scheme=JACOBI, iterations=1 and "
                         f"region_sleep=False, got scheme={s.scheme.name}, iterations={s.iterations}, "
                         f"region_sleep={s.region_sleep}")


def _settings_validate(self) -> "Settings":
    """Already checked: itself (a Settings is checked when it is made, ``dataclasses.replace`` included)."""
    return self


def _settings_substep_dt(self) -> float:
    """h = frame_dt / substeps (s)."""
    return self.frame_dt / self.substeps


Settings = dataclasses.make_dataclass(
    "Settings", _settings_fields(), frozen=True,
    namespace={"__post_init__": _check, "validate": _settings_validate, "substep_dt": property(_settings_substep_dt)})
Settings.__module__ = __name__
Settings.__doc__ = """The validated options a solver runs on: every field of :class:`Config`, :class:`Tuning` and
:class:`Execution`, flat, checked when made (``Config.validate()``, ``dataclasses.replace``), frozen;
plus ``substeps_requested``: the ``substeps`` asked for where ``max_substep`` raised them (else None)."""

PRESETS: dict[str, dict] = {
    "default": {},
    "interactive": {"substeps": 5},
    "dataset": {"contact": Strategy.OPT, "contact_every": 1, "contact_linear": False},
    "robot_pads": {"contact": Strategy.OPT, "substeps": 5, "contact_every": 1, "contact_linear": False},
}
