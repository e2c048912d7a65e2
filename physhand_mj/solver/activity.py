"""What runs this frame: the contact work set, gated blocks of the recorded frame, the frame's tally.

The solver records a frame once (a list of launches; a CUDA graph on GPUs). Contact work is
recorded into *gated blocks* that run only when the scene calls for them:

    level 0  an object may be near the hand: the frame broadphase (contact.record_frame) and
             everything after it. On the CPU the host decides it before the frame from the skin's
             bounding box (free to read there) and the objects' bounding spheres / planes, grown by
             Config.contact_frame_margin (the same margin the frame broadphase uses); on CUDA the
             block always runs (the skin is not on the host).
    level 1  the frame broadphase kept a triangle (its count, ``Contact.cand_count``): the contact
             stages, the tether, the penetration metrics. On the CPU the count is read on the host
             for free. On CUDA the frame broadphase runs first, on its own (``Solver.step``: two
             ops), its count comes to pinned host memory with one sync, and the host launches one
             of two recorded graphs: the frame with these blocks or without them. (A conditional
             graph node, ``wp.capture_if``, cannot hold them: ``wp.Mesh.refit`` allocates scratch
             memory on CUDA, which a conditional body may not; measured on an H100, Warp 1.19.)
    level 2  the previous contact pass of a stage moved a vertex: passes 2..N. On the CPU the host
             reads that pass's two counters. On CUDA (graphs on, tiled feature queries: no refit
             inside a pass) each such pass is a conditional graph node, ``wp.capture_if`` on a flag
             that the previous pass's last launch (thread 0 of ``broadphase.keep_moved``) sets
             from those counters on the device. Each pass's block sits inside the one before
             (``Contact._record_later_passes``), so a skipped pass skips the rest with it: one test,
             one node, however many passes ``Config.contact_passes`` allows.

With no object within the frame margin no contact kernel runs (CPU: not even the frame
broadphase; CUDA: the frame broadphase and one sync only). Nothing inside a closed block could change the
result: skin farther than the margin from every object has no decision point below
``contact_margin``, no feature near it, no penetrating sample, and nothing for the tether to undo.
Objects enter and leave the work set through these tests every frame.

:meth:`Activity.report` turns the list lengths the frame already copies back (no extra host sync)
into what ran: objects near, triangles in the frame list / stage lists / tested by the passes,
features listed, ops run (launches, memsets, refits) and of those the contact's.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.types import GeomType


class Activity:
    """The gated blocks of one solver's recorded frame and the host-side work-set test."""

    def __init__(self, solver):
        self.solver = solver
        self.device = solver.device
        self.enabled = bool(solver.config.skip_idle)
        c = solver.contact
        # CUDA: level 1 decided on the host from the frame broadphase run ahead (Solver.step); a
        # test may set it on the CPU before the first frame to run that path there
        self.gate_ahead = bool(self.enabled and self.device.is_cuda and c is not None)
        # CUDA: a contact pass after one that moved nothing is a conditional graph node
        # (wp.capture_if) that skips it on the device; not with the BVH feature path, whose per-pass
        # skin refit allocates (a conditional body may not). A test may set it on the CPU before the
        # first frame (capture_if then reads the flag on the host)
        cfg = solver.config
        self.conditional = bool(self.enabled and self.device.is_cuda and cfg.cuda_graph and c is not None
                                and (not cfg.feature_contact or c.tiled_features))
        self.open1 = True  # CUDA: the frame broadphase kept a triangle (set by Solver.step before the frame)
        self.near = np.ones(1, np.int32)  # level 0 flag, decided on the host before the frame (CPU)
        self.last_open1 = True  # whether the last frame ran its level-1 contact block (report)
        self.objects_near = -1  # objects (MuJoCo bodies) in the work set; -1: not decided on the host
        cpu = c is not None and not self.device.is_cuda
        self._cand = c.cand_count.numpy() if cpu else None
        self._counters = c.counters.numpy() if cpu else None  # views: CPU memory
        self.reset_recording()

    def reset_recording(self) -> None:
        self.gates: list[_Gate] = []

    @property
    def passes_gated(self) -> bool:
        """Whether a contact pass can be skipped whole (level 2): on the CPU's host test or CUDA's
        conditional nodes; not with gating off (``skip_idle=False``) or CUDA without conditional nodes,
        where every pass runs (Config.tuning.contact_pass_tol is then not applied: Contact.finish_recording)."""
        return bool(self.enabled and (self.conditional or not (self.device.is_cuda or self.gate_ahead)))

    # -- recording -------------------------------------------------------------------------------
    def gate(self, sub: list, level: int, slots=(), flag=None) -> "_Gate":
        """An op running ``sub`` when the frame's contact has work at ``level`` (see the module doc;
        level 2: a contact pass, run when the previous pass moved a vertex: counters at ``slots``,
        on CUDA the device ``flag`` the previous pass's last launch sets from them)."""
        g = _Gate(self, sub, level, tuple(slots))
        if level == 2 and self.conditional:  # the device decides: capture_if on the flag
            if flag is None:
                raise ValueError("a conditional contact pass needs the device flag its previous pass sets")
            g.cond = flag
        self.gates.append(g)
        return g

    # -- per frame, host -------------------------------------------------------------------------
    def begin_frame(self, state) -> None:
        """Decide level 0 on the CPU: is any object's bounding sphere (a plane: its half-space)
        within Config.contact_frame_margin of the skin's bounding box?"""
        c = self.solver.contact
        if c is None or self.device.is_cuda or self.gate_ahead:
            self.objects_near = -1 if c is not None else 0
            return
        m = self.solver.model
        skin = state.x.numpy()[: m.n_skin]  # a view: CPU memory
        lo, hi = skin.min(axis=0), skin.max(axis=0)
        self.objects_near = objects_near(c.objects, lo, hi, self.solver.config.contact_frame_margin)
        self.near[0] = int(self.objects_near > 0)

    def report(self, counters: np.ndarray, feat_count: int, contact) -> dict:
        """What ran in the last frame, from the frame's list lengths (host copies)."""
        near = bool(self.near[0]) or not self.enabled
        cand = int(counters[0]) if near else 0
        gating1 = self.enabled and (not self.device.is_cuda or self.gate_ahead)
        if self.gate_ahead:
            near = True  # level 0 is not decided on the host then
        open1 = near and (cand > 0 or not gating1)
        self.last_open1 = open1  # (the frame ran its contact block: Contact.feature_motion's reports are its own)
        contact_ops = sum(g.leaf_ops(open1, counters) for g in self.gates
                          if g.top and (near if g.level == 0 else open1)) + self.ahead_ops
        ops = self.ungated_ops + contact_ops
        tested = int(sum(int(counters[s]) for s in contact.pass_slots)) if open1 else 0
        stage = int(sum(int(counters[a]) for a, *_ in contact._stage_slots)) if open1 else 0
        return dict(objects_near=self.objects_near, triangles_frame=cand, triangles_stage=stage,
                    triangles_tested=tested, features_listed=int(feat_count) if open1 else 0,
                    ops_run=ops, contact_ops_run=contact_ops)

    def finish_recording(self, ops: list, ahead: list = ()) -> None:
        """Count the recorded frame's ops outside the gated blocks, and the contact ops run ahead
        of it (``ahead``: CUDA's frame broadphase and its counter reset, Solver.step)."""
        self.ungated_ops = sum(1 for op in ops if not isinstance(op, _Gate))
        self.ahead_ops = len(ahead)


class _Gate:
    """A block of recorded ops running when its level is open: on the CPU decided on the host; on
    CUDA level 1 is decided on the host before the frame's graph (one graph per outcome), level 0
    always runs."""

    def __init__(self, activity: Activity, sub: list, level: int, slots: tuple = ()):
        self.activity, self.sub, self.level, self.slots = activity, sub, level, slots
        self.top = True
        for op in sub:
            if isinstance(op, _Gate):
                op.top = False

    cond = None  # level 2 under Activity.conditional: the device flag capture_if reads
    moved_enough = None  # level 2 with Config.tuning.contact_pass_tol: did the last pass move enough? (the CPU's
    # gate asks it; on CUDA keep_moved sets the conditional node's flag alike and this counts the ops run)

    def __call__(self):
        a = self.activity
        if not a.enabled:
            self.run_all()
        elif self.cond is not None:  # a contact pass, skipped on the device when the last one moved nothing
            wp.capture_if(self.cond, on_true=self.run_all)
        elif a.gate_ahead or a.device.is_cuda:  # (level 2 always runs on CUDA without conditional nodes)
            if self.level != 1 or not a.gate_ahead or a.open1:
                self.run_all()
        elif a.near[0] and (self.level == 0 or a._cand[0]) and (
                self.level < 2 or (any(a._counters[s] for s in self.slots)
                                   and (self.moved_enough is None or self.moved_enough()))):
            self.run_all()

    def run_all(self):
        for op in self.sub:
            op()

    def leaf_ops(self, open1: bool, counters) -> int:
        """Ops this block runs (nested blocks of level 1 only when ``open1``, of level 2 when one of
        their counters is not zero)."""
        return sum(1 if not isinstance(op, _Gate) else op.leaf_ops(open1, counters) if op.opens(open1, counters)
                   else 0 for op in self.sub)

    def opens(self, open1: bool, counters) -> bool:
        if self.level == 0:
            return True
        if self.level == 1:
            return open1
        a = self.activity
        gating = a.enabled and (self.cond is not None or not (a.device.is_cuda or a.gate_ahead))
        return open1 and (not gating or (any(counters[s] for s in self.slots) and (
            self.moved_enough is None or self.moved_enough())))


def objects_near(objects, lo: np.ndarray, hi: np.ndarray, margin: float) -> int:
    """Objects (geoms grouped by ``obj``) with a geom within ``margin`` (m) of the box [lo, hi]: a
    geom's bounding sphere about its origin, a plane's half-space below its local z = 0."""
    h = objects._host
    n = len(objects)
    if not n:
        return 0
    pose = h["pose"][:n].astype(np.float64)  # [p, q x y z w]
    p, q = pose[:, :3], pose[:, 3:]
    near = np.zeros(n, bool)
    plane = h["gtype"][:n] == int(GeomType.PLANE)
    if np.any(~plane):  # distance from the sphere's centre to the box
        d = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
        near |= ~plane & (d - h["radius"][:n] <= margin)
    if np.any(plane):  # the lowest box corner along the plane's normal (local z)
        x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        nrm = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)
        low = np.where(nrm > 0, lo, hi)  # the corner deepest below the plane
        near |= plane & (np.einsum("ij,ij->i", low - p, nrm) <= margin)
    return int(len(np.unique(h["obj"][:n][near])))
