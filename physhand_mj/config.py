"""The solver's options (:class:`Config`, its presets and the substep stability limit), re-exported
by :mod:`physhand_mj.types`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from physhand_mj.enums import NonFinite, Placement, Scheme, Strategy, enum_field


@dataclass
class Config:
    """Solver options. Every quantity is SI; compliance ``alpha = 1/k`` for an energy
    ``U = C^2 / (2 alpha)`` of the paper's constraint function ``C``.

    Attributes:
      frame_dt: simulated time per ``Solver.step`` call (s); the paper and MuJoCo scenes use 0.005.
      substeps: substeps per frame (Algorithm 1, line 1: ``h = frame_dt / substeps``).
      max_substep: longest substep the solver runs (s; default 2 ms). ``validate()`` raises
        ``substeps`` to ``ceil(frame_dt / max_substep)`` where ``frame_dt / substeps`` is longer
        (a 20 ms frame runs 10 substeps, costing 10 substeps' time), since the Jacobi XPBD flesh sags
        and inverts under gravity alone at 5-10 ms substeps (docs/stability.md). None keeps the
        count as given and warns (the run then stays finite and reports the inversions).
      substeps_requested: the ``substeps`` asked for where ``validate()`` raised it (else None).
      iterations: constraint passes per substep (Algorithm 1, lines 7-13; the paper uses 1).
      gravity: (3,) acceleration in the solver's world frame (m/s^2); zeros to switch it off.
      damping: velocity damping rate (1/s), ``v *= exp(-damping h)`` per substep.
      edge_compliance_skin / edge_compliance_flesh: Eq. 2 (m/N) on edges whose two vertices are both
        skin / any other edge.
      volume_compliance: Eq. 3, per unit volume (1/Pa = inverse bulk modulus); a tet of rest volume V
        gets ``alpha = 36 V volume_compliance`` so that ``U = (dV)^2 / (2 V volume_compliance)``.
      attach_compliance: Eq. 4-5 (m/N).
      smooth_compliance: Eq. 6 (rad^2/J = 1/(N m)).
      edges, volumes, attachment, smoothness: switch a constraint family on/off (the Fig. 6 ablation).
      attach_skin: also attach skin vertices to their nearest skeleton vertex (the paper attaches
        flesh vertices only).
      scheme: :class:`Scheme`; relaxation: Jacobi over-relaxation factor (1 = plain averaging).
      jacobi_gather: Jacobi only: each constraint stores its corrections in slots of its own and
        every vertex sums its slots in a fixed order (solver/gather.py) instead of adding them with
        float atomics: the solver then repeats bit for bit on CUDA (the contact keeps its atomics),
        and batches run faster there (H100: ~10,900 against ~6,900 hand-frames/s); one hand's frame
        costs about the same (0.45 against 0.42 ms) and the CPU's 10-20 % more, with the atomic
        result bit for bit. None (default): batches of 2 or more worlds on CUDA gather
        (BatchedHands) unless they take the fused substep (``fused_substep``: from 0.3 worlds per
        SM, whose fixed-point sum repeats bit for bit too), every other solver adds
        atomically; True / False: always / never.
      nonfinite: :class:`NonFinite` policy.
      contact: :class:`Strategy` for the skin-object decision points (used when the solver has
        objects); contact_placement: :class:`Placement` of the correction in the substep;
        contact_passes: query + Eq. 9 projection rounds per placement (at most: a pass queries only
        triangles the previous pass moved); contact_every: run the contact stage every this many
        substeps (count; always in the frame's last substep, so the frame ends corrected; 1 = every
        substep, Algorithm 1): fewer stages a frame, the skin between them follows the solver alone
        (docs/activity.md: every=2 saves a quarter of the H100 demo frame and leaves residue in 13
        of the hard cases' 600 held frames, none at 1); contact_linear: with contact_every > 1, a
        substep without a stage holds the skin against the planes the last stage linearised the
        SDF to at its triangles' decision points, and against the object feature points it kept
        (contact/linear.py: two query-free hold passes; contact_every=2 with it keeps the hard
        cases at 0 of 600, docs/activity.md; not with fused_stage); contact_pass_tol: in every contact stage but
        the frame's last, a pass runs only when the pass before it moved some vertex by more than
        this (m; 0: by anything, every stage runs until a pass moves nothing); the frame's last stage
        always runs to the end, so what a frame ends with is cleared as before; passes that only
        confirm a stage's last small moves are skipped where the next substep's stage re-tests the
        skin anyway (benchmarks/pass_moves.py, docs/activity.md); applied only where a pass can be
        skipped whole (the CPU's gate, CUDA's conditional nodes: not with skip_idle=False, CUDA
        without conditional nodes, or fused_stage); contact_margin: the stage broadphase's margin (m; covers how
        far one stage's corrections drag a triangle that did not penetrate itself);
        contact_frame_margin: the frame broadphase's margin (m; must cover how far skin and objects
        move toward each other in one frame: 1 cm at 5 ms frames is 2 m/s); contact_offset: how far
        outside an object Eq. 9 puts a triangle's decision point (m; 4 um: float32 rounding of
        ~0.1 m coordinates is ~10 nm, and the lattice search misses a faceted mesh's minimum by
        up to ~3.5 um: the HOI bowl's order-9 check found 6 samples up to 2.3 um inside at 1 um,
        2 up to 0.5 um at 3 um, none at 4 um (nor order 17); docs/contact.md);
        feature_contact: also push the skin off object features (corners, tips, sharp edges) that lie
        inside it (contact/features.py: the object's side of the contact, which the skin's decision
        points cannot see when a feature is smaller than a triangle); feature_offset: how far
        outside the skin such a feature point ends (m; 60 um: skin bent over an edge bulges past
        it between two samples, which a 4x denser check finds up to 30 um inside the skin when
        features end 1 um out; 50-70 um clear the hard cases, 80 um and more let a 1 mm plate
        tunnel: docs/contact.md); feature_spacing: the distance between two feature points along
        an object's sharp edges (m; 0.25 mm: at 0.5 mm the skin wrapped over a 1 mm plate's edge in
        the palm bulged up to 21 um past the 60 um standoff between two samples in held frames;
        the bulge grows with the square of the spacing); feature_last: end every contact stage
        with one more feature push after the last pass's Eq. 9 (the two alternate within a pass,
        and 8 passes could end with Eq. 9 having moved the skin back over a corner); with it and
        the two settings above 0 of 600 held hard-case frames left anything inside the skin on the
        CPU and an H100, 26 and 18 without the three (docs/contact.md, held frames);
        feature_last_offset: how far outside the skin that last push puts a feature point (m; None:
        feature_offset, as before the option). A smaller last push drags less of the skin shared
        with a thin object's other face: on the CPU, over 31 paths of the 1 mm plate started 4 mm
        deep in the palm, 8 kept a held frame with residue at 60 um and 1 at 6 um, and the 24 hard
        cases on four paths 4 of 96 runs against 0; but the knife held 20 mm through the fingertip
        kept 1-2 tets inverted after it left on 1 of 9 paths at 6 um (0 of 9 at 60 um), so the
        default stays (docs/contact.md, the last push's stand-off);
        feature_slack: the least motion of the skin within one frame that the object's feature
        points are listed and their patches (the local winding number's, contact/winding.py) sized
        for (m, > 0; 4 mm: a held grasp's skin jitters up to 1.5 mm a frame at single vertices): a
        feature point d from the skin at the frame's start is listed when d is within
        feature_list_share x the slack plus contact_margin (or the pseudo normals put it inside),
        and its patch holds the skin triangles within d plus the slack (not within
        contact_frame_margin: 4-8 x fewer patch entries on the box grasp); each frame the slack
        follows 2.5 x the skin's largest move near the points in the last frame with contact, up
        to contact_frame_margin, and a frame in which a skin vertex moved far enough, near enough
        to a point, to spoil its list is reported (``feature_slack_exceeded``) and warned about
        (docs/contact.md); at contact_frame_margin or more: every feature point within that
        margin, patches of that radius (the lists before 2026-11-27);
        feature_list_share: how far past contact_margin a feature point is listed, as a share of
        the slack (a ratio, 0.5-1; 0.5: d <= contact_margin + slack / 2, which the frame's check
        certifies under the bound on the skin's move the patches need anyway; 1: the lists of the
        first three sessions of 2026-11-27, half of whose box points no pass could push in time);
        side_aware: where the SDF gradient at a decision point points out of the hand, leave the
          object along the triangle's inward normal instead of by Eq. 9 (contact/query.py
          ``project``; fixes deep starts past an object's mid-plane and thin walls). Both need a
          closed skin and are on by default; off (and skin_tether 0), the contact is the paper's
          (docs/contact.md);
        skin_tether: the farthest a skin vertex may be from its rigidly carried position (m; its
          nearest bone at rest carries it at its rest offset: Model.skin_body), enforced at the end
          of every substep of a solver with objects; 0 switches it off. 25 mm: flexed keyframes without contact reach 17 mm at
          the thumb web, while a start with a bone inside an object (no penetration-free skin
          exists) would otherwise drag skin vertices several centimetres (docs/contact.md);
        object_metrics: evaluate the second penetration measure (object surface points inside the
        closed skin, contact/inside.py) at the end of every frame; otherwise ``SoftHand.metrics`` /
        ``penetration`` evaluate it when called (it costs about as much as a CPU frame);
        reuse_outside: that measure asks again only the object points whose answer could have
          changed: a point found outside the skin at distance d stays outside until its world's skin
          (its farthest-moving vertex) and its object together have moved d since (the skin would
          have to cross it); False asks every point every time (the same answers:
          tests/test_hard_contact.py, tests/test_batch.py, tests/test_winding.py);
        mesh_grid: node spacing (m) of each mesh object's distance grid (contact/objects.mesh_grid),
          which answers the broadphase's and the metrics' queries it proves farther than 1 mm
          outside the mesh (a lower bound of the distance) without the BVH walk; the broadphase
          re-asks exactly where a bound keeps a triangle and the decision points never use it, so
          the contact's results are unchanged. 0: no grid (docs/contact.md);
        multires_samples / multires_rounds: Algorithm 2's samples per round and rounds (default
        21 x 2 = 42 queries: an order-5 first round catches narrow penetrations at sharp rims that
        10 x 3 and the paper's 16 x 2 miss, docs/contact.md); opt_queries: Frank-Wolfe queries of OPT (the paper's
        baseline: 32); substep_metrics: evaluate the penetration metrics after every substep (for
        logs), not only at the end of the frame; frame_metrics: the skin measure at every frame's end
        (``step()``'s ``penetration_*``, the rollout log); False (a batch that reads its measures at
        its end) records none: ``SoftHand.metrics`` / ``BatchedHands.penetration`` measure on demand.
      device: Warp device, ``"cpu"`` or ``"cuda"`` / ``"cuda:0"``; None picks Warp's default.
      cuda_graph: capture one frame as a CUDA graph on CUDA devices.
      tiled_contact: on CUDA, run multires with a block of 32 threads per triangle (a lane per
        lattice sample; needs multires_samples < 32), else a thread per triangle. None (default):
        tiled for one hand (H100: 2.5 against 4.1 ms a frame with a sphere pressing the hand), a
        thread per triangle for batched worlds, where the launch's block per skin triangle of every
        world, nearly all idle, cost 2.8 x the batch's throughput (3,282 against 9,112
        hand-frames/s at W = 1024, docs/scale.md).
      multires_registers: CUDA batches' per-thread multires kernel: 0 the kernel of every strategy, N a
        copy specialised to MULTIRES capped at N registers a thread (same answers); None (default): 128
        with a mesh object, else 0 (docs/scale.md); multires_block_dim: that copy's threads a block.
      sample_lanes: multires with a lane per lattice sample (contact/query_lanes.py; the same answers),
        off by default: no faster on an H100 batched, twice the frame on one hand (docs/scale.md).
      tiled_features: on CUDA, run the object's side (feature_contact: each contact stage's feature
        list and every pass's feature push) with a block of 128 threads per listed feature point,
        the lanes scanning the point's patch (the skin triangles within contact_frame_margin of it
        at the frame's start; with feature_winding off, the frame's broadphase list of skin
        triangles) for the exact closest skin point and its sign, instead of one thread per feature
        walking the skin's BVH (refitted before every stage and pass); the same closest point
        (distance ties: the lowest triangle index) and decisions (contact/features.py). None
        (default): blocks for one hand and batches under 64 worlds, and for larger batches (with
        feature_winding) a thread per listed feature scanning its patch (H100, the HOI box grasp at
        W = 256: 3,302 against 1,907 hand-frames/s; at W = 16 627 against 1,349; docs/scale.md). The CPU always walks the BVH.
      feature_winding: decide whether an object feature point is inside the skin by its local
        winding number (the solid angles of the skin triangles within contact_frame_margin of it,
        summed every pass, plus the rest's from Warp's fast winding number at the frame's start;
        contact/winding.py) instead of the pseudo normals alone, which take points in front of a
        squeezed, turned-over skin triangle as inside and push the skin for nothing. On the CPU it
        confirms the points the pseudo normal takes as inside; on CUDA the feature kernels scan the
        point's triangles (instead of the frame's whole list) and take every sign from it.
      fused_stage: run each contact stage of a single hand with multires as one launch
        (contact/stage.py): on CUDA a block per SM walks the stage's lists, feature pushes, decision
        points and applies with grid barriers between them (on the CPU one thread), the passes a
        loop that stops after one that moved nothing; the recorded stage's decisions with CUDA's
        feature kernels (on the CPU, with those forced, bit for bit; the CPU's own BVH feature path
        differs). Off by default: it is not faster. H100 (2026-11-25): the demo's held frame 4.15-4.18
        against 4.03-4.36 ms, closing 6.3-6.4 against 5.8-5.9, the hard cases' held frames 14.7
        against 4.4 ms (0 of 600 with residue); a pass costs the latency of its phases, not of its
        launches (docs/activity.md). Needs the GPU's SMs to itself (a stage that could not run all
        its blocks at once raises SolverError). Batches and the other strategies keep the recorded stage.
      skip_idle: run the contact work only when an object is within contact_frame_margin of the
        skin (physhand_mj/solver/activity.py: with none near, no contact kernel runs; results are the
        same either way); False runs every recorded contact launch every frame (for comparisons).
      sleep_speed: the hand falls asleep after ``sleep_frames`` frames (count) in which no soft
        vertex ended faster than this (m/s; 0: never sleep), when no object is within
        contact_frame_margin and no bone moves relative to the others by more than
        ``sleep_bone_motion`` (m per frame). Asleep, a frame is one kernel launch (plus the report
        resets): every vertex rides rigidly with its bone (the one of its nearest skeleton vertex at
        rest) from the last solved shape, with that bone's velocity. It wakes (and must settle
        again) when an object comes near, a bone moves relative to the others by more than
        ``sleep_bone_motion`` since it fell asleep, the first bone turns by more than 2 degrees
        (gravity turns in the hand) or its velocity changes by more than ``sleep_speed``
        (physhand_mj/solver/activity.py).
      region_sleep: parts of the hand (the palm, the thumb, each finger) sleep alone under the same
        tests, each on its own bones, vertices and skin box: asleep, a region's soft vertices ride
        their carrier bones rigidly (kinematic, as the skeleton) and constraints among them return
        at once; it wakes when one of its bones moves relative to the first bone or an object comes
        within contact_frame_margin (physhand_mj/solver/regions.py). One world; off by default.
      fused_substep: a substep's three Jacobi groups (edges, tets, dihedrals, each averaged) in one
        launch with a block per world holding the world's positions and corrections in shared
        memory (physhand_mj/solver/fused.py) instead of five launches through global memory. Same
        math and groups; on the CPU the result is the atomic path's bit for bit (Warp's CPU runs a
        block as one lane, unless ``wp.config.enable_cpu_blocks``) and the solver frame ~1.2 x
        faster (one hand to 4 worlds; it also makes the substep's start where no contact stage
        comes before the constraints); on CUDA the corrections' sum order differs
        (shared-memory atomics) and a block holds one world, so it pays for batches only (H100,
        fixed-point sum: 2.95 x the gathers' solver frame at 132 worlds, 1.90 x at 64, 1.20 x at
        32, 0.69 x at 16, 0.12 x for one hand). Needs the Jacobi scheme, one iteration, no region sleep, each world's movable
        vertices first, and 12 bytes of shared memory per vertex and per soft vertex in a block,
        plus 4 per thread on CUDA (the embedded hand: 207,504 B; an H100/H200 block: 227 KB;
        Warp's CPU arena: 256 KB). None (default): on the CPU where those hold and
        ``jacobi_gather`` is not True; on CUDA for a BatchedHands of at least 0.3 worlds per SM
        (H100: 40; solver/fused_choice.py ``cuda_auto``); True: always (ValueError where it cannot
        run); False: never. How a group's corrections are summed per vertex:
        ``physhand_mj.solver.fused.SUM`` ("scatter" or "gather", docs/solver.md).
    """

    frame_dt: float = 0.005
    substeps: int = 10
    max_substep: float | None = 2.0e-3
    substeps_requested: int | None = None
    iterations: int = 1
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    damping: float = 2.0
    edge_compliance_skin: float = 1.0e-3
    edge_compliance_flesh: float = 1.0e-2
    volume_compliance: float = 1.0e-6
    attach_compliance: float = 1.0e-3
    smooth_compliance: float = 10.0
    edges: bool = True
    volumes: bool = True
    attachment: bool = True
    smoothness: bool = True
    attach_skin: bool = False
    scheme: Scheme = Scheme.JACOBI
    relaxation: float = 1.0
    jacobi_gather: bool | None = None
    nonfinite: NonFinite = NonFinite.RECOVER
    contact: Strategy = Strategy.MULTIRES
    contact_placement: Placement = Placement.AFTER
    contact_passes: int = 8
    contact_every: int = 1
    contact_linear: bool = False
    contact_pass_tol: float = 0.0
    contact_margin: float = 5.0e-4
    contact_frame_margin: float = 1.0e-2
    contact_offset: float = 4.0e-6
    feature_offset: float = 6.0e-5
    feature_last_offset: float | None = None
    feature_spacing: float = 2.5e-4
    feature_slack: float = 4.0e-3
    feature_list_share: float = 0.5
    multires_samples: int = 21
    multires_rounds: int = 2
    opt_queries: int = 32
    substep_metrics: bool = False
    frame_metrics: bool = True
    feature_contact: bool = True
    side_aware: bool = True
    skin_tether: float = 0.025
    object_metrics: bool = False
    reuse_outside: bool = True
    mesh_grid: float = 2.0e-3
    device: str | None = None
    cuda_graph: bool = True
    tiled_contact: bool | None = None
    multires_registers: int | None = None
    multires_block_dim: int = 256
    sample_lanes: bool = False
    tiled_features: bool | None = None
    feature_winding: bool = True
    feature_last: bool = True
    fused_stage: bool = False
    skip_idle: bool = True
    region_sleep: bool = False
    fused_substep: bool | None = None
    sleep_speed: float = 3.0e-3
    sleep_frames: int = 10
    sleep_bone_motion: float = 1.0e-5

    def validate(self) -> "Config":
        """Raise ValueError naming the option to fix; returns self."""
        def pos(name):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"Config.{name} must be a finite number > 0, got {v!r}")

        def nonneg(name):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"Config.{name} must be a finite number >= 0, got {v!r}")

        pos("frame_dt")
        for name in ("substeps", "iterations", "contact_passes", "contact_every", "multires_rounds", "opt_queries"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ValueError(f"Config.{name} must be an integer >= 1, got {v!r}")
        g = np.asarray(self.gravity, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"Config.gravity must be 3 finite numbers (m/s^2), got {self.gravity!r}")
        for name in ("damping", "edge_compliance_skin", "edge_compliance_flesh", "volume_compliance",
                     "attach_compliance", "smooth_compliance"):
            nonneg(name)
        if not (0.0 < self.relaxation < 2.0):
            raise ValueError(f"Config.relaxation must lie in (0, 2), got {self.relaxation!r}")
        if not (self.tiled_contact is None or isinstance(self.tiled_contact, (bool, np.bool_))):
            raise ValueError(f"Config.tiled_contact must be None (one hand: tiled), True or False, got {self.tiled_contact!r}")
        r = self.multires_registers
        if r is not None and not (isinstance(r, (int, np.integer)) and not isinstance(r, bool)
                                  and (r == 0 or 32 <= r <= 255)):
            raise ValueError(f"Config.multires_registers must be None (chosen per run), 0 (the generic kernel) or an "
                             f"integer from 32 to 255 (registers a thread), got {r!r}")
        if not isinstance(self.sample_lanes, (bool, np.bool_)):
            raise ValueError(f"Config.sample_lanes must be True or False, got {self.sample_lanes!r}")
        b = self.multires_block_dim
        if not (isinstance(b, (int, np.integer)) and not isinstance(b, bool) and 32 <= b <= 1024 and b % 32 == 0):
            raise ValueError(f"Config.multires_block_dim must be a multiple of 32 from 32 to 1024 (threads a block), "
                             f"got {b!r}")
        if not isinstance(self.region_sleep, (bool, np.bool_)):
            raise ValueError(f"Config.region_sleep must be True or False, got {self.region_sleep!r}")
        if not (self.fused_substep is None or isinstance(self.fused_substep, (bool, np.bool_))):
            raise ValueError(f"Config.fused_substep must be None (the CPU's and large CUDA batches' default), True or False, got "
                             f"{self.fused_substep!r}")
        if not isinstance(self.fused_stage, (bool, np.bool_)):
            raise ValueError(f"Config.fused_stage must be True or False, got {self.fused_stage!r}")
        if not isinstance(self.contact_linear, (bool, np.bool_)):
            raise ValueError(f"Config.contact_linear must be True or False, got {self.contact_linear!r}")
        if self.contact_linear and self.fused_stage:
            raise ValueError("Config.contact_linear holds the skin between recorded contact stages: set "
                             "fused_stage=False with it")
        if not (self.tiled_features is None or isinstance(self.tiled_features, (bool, np.bool_))):
            raise ValueError(f"Config.tiled_features must be None (blocks for one hand, a thread per feature for "
                             f"batches), True or False, got {self.tiled_features!r}")
        if not isinstance(self.reuse_outside, (bool, np.bool_)):
            raise ValueError(f"Config.reuse_outside must be True or False, got {self.reuse_outside!r}")
        if not (self.jacobi_gather is None or isinstance(self.jacobi_gather, (bool, np.bool_))):
            raise ValueError(f"Config.jacobi_gather must be None (on CUDA), True or False, got {self.jacobi_gather!r}")
        if not (isinstance(self.multires_samples, (int, np.integer)) and self.multires_samples >= 3):
            raise ValueError(f"Config.multires_samples must be an integer >= 3, got {self.multires_samples!r}")
        nonneg("contact_margin")
        nonneg("contact_pass_tol")
        nonneg("skin_tether")
        nonneg("contact_frame_margin")
        nonneg("contact_offset")
        nonneg("feature_offset")
        v = self.feature_last_offset
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0):
            raise ValueError(f"Config.feature_last_offset must be None (feature_offset's stand-off) or a distance "
                             f">= 0 in m (e.g. 6e-6), got {v!r}")
        if not (isinstance(self.feature_slack, (int, float)) and not isinstance(self.feature_slack, bool)
                and math.isfinite(self.feature_slack) and self.feature_slack > 0):
            raise ValueError(f"Config.feature_slack must be a distance > 0 in m (e.g. 4e-3), got {self.feature_slack!r}")
        if not (isinstance(self.feature_list_share, (int, float, np.floating, np.integer))
                and not isinstance(self.feature_list_share, bool)
                and 0.5 <= self.feature_list_share <= 1.0):
            raise ValueError(f"Config.feature_list_share must be a ratio in [0.5, 1] (the share of the slack past "
                             f"contact_margin within which feature points are listed), got {self.feature_list_share!r}")
        if not (isinstance(self.feature_spacing, (int, float, np.floating, np.integer))
                and not isinstance(self.feature_spacing, bool) and math.isfinite(self.feature_spacing)
                and self.feature_spacing > 0):
            raise ValueError(f"Config.feature_spacing must be a distance > 0 in m (e.g. 2.5e-4), "
                             f"got {self.feature_spacing!r}")
        nonneg("mesh_grid")
        nonneg("sleep_speed")
        nonneg("sleep_bone_motion")
        if not (isinstance(self.sleep_frames, int) and self.sleep_frames >= 1):
            raise ValueError(f"Config.sleep_frames must be an integer >= 1, got {self.sleep_frames!r}")
        if self.contact_frame_margin < self.contact_margin:
            raise ValueError(f"Config.contact_frame_margin ({self.contact_frame_margin} m) must be at least "
                             f"Config.contact_margin ({self.contact_margin} m)")
        if self.max_substep is not None:
            ms = self.max_substep
            if isinstance(ms, bool) or not isinstance(ms, (int, float, np.floating, np.integer)) or not (
                    math.isfinite(ms) and ms > 0):
                raise ValueError(f"Config.max_substep must be None or a finite number of seconds > 0 (e.g. 0.002), "
                                 f"got {ms!r}")
            if self.frame_dt / self.substeps > ms * (1 + 1e-9):
                if self.substeps_requested is None:
                    self.substeps_requested = int(self.substeps)
                self.substeps = int(math.ceil(self.frame_dt / ms - 1e-9))
        elif self.frame_dt / self.substeps > MAX_STABLE_SUBSTEP * (1 + 1e-9):
            from physhand_mj.warn import warn_user

            need = math.ceil(self.frame_dt / MAX_STABLE_SUBSTEP - 1e-9)
            warn_user(f"Config: substeps of {self.frame_dt / self.substeps * 1e3:.3g} ms (frame_dt {self.frame_dt} s / "
                      f"substeps {self.substeps}) are longer than {MAX_STABLE_SUBSTEP * 1e3:g} ms: the flesh sags "
                      f"and inverts under gravity alone and does not recover (docs/stability.md); use substeps "
                      f">= {need} (or leave Config.max_substep at its default, which does)")
        self.contact = enum_field(Strategy, self.contact, "contact")
        self.contact_placement = enum_field(Placement, self.contact_placement, "contact_placement")
        self.scheme = enum_field(Scheme, self.scheme, "scheme")
        self.nonfinite = enum_field(NonFinite, self.nonfinite, "nonfinite")
        if self.fused_substep and (self.scheme != Scheme.JACOBI or self.iterations != 1 or self.region_sleep):
            raise ValueError("Config.fused_substep needs scheme=JACOBI, iterations=1 and region_sleep=False, got "
                             f"scheme={self.scheme.name}, iterations={self.iterations}, region_sleep={self.region_sleep}")
        return self

    @property
    def substep_dt(self) -> float:
        """h = frame_dt / substeps (s)."""
        return self.frame_dt / self.substeps

    @classmethod
    def preset(cls, name: str, **overrides) -> "Config":
        """A named setting of the accuracy sweep's recommendation table (docs/accuracy.md), with
        ``overrides`` on top: ``"default"`` (= ``Config()``), ``"interactive"`` (5 substeps: half the
        frame at the same end-of-frame depth on the sweep's workloads, but the flesh about 2.5-3 x
        softer under gravity and held presses at the palm 1.5-6 x deeper), ``"dataset"`` (opt
        decision points: the shallowest held skin on the CPU sweep) and ``"robot_pads"`` (opt at 5
        substeps: sharp rigid objects in a control loop)."""
        if name not in PRESETS:
            raise ValueError(f"unknown Config preset {name!r}: choose one of {sorted(PRESETS)}")
        return cls(**{**PRESETS[name], **overrides}).validate()


MAX_STABLE_SUBSTEP = 2.0e-3  # s: longer substeps collapse the flesh (tests/stress/test_stress_fast.py: 5 and 10 ms do)

PRESETS: dict[str, dict] = {
    "default": {},
    "interactive": {"substeps": 5},
    "dataset": {"contact": Strategy.OPT},
    "robot_pads": {"contact": Strategy.OPT, "substeps": 5},
}
