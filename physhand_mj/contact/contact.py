"""The contact stage of a substep (Algorithm 1, line 6): broadphase, decision points, Eq. 9.

:class:`Contact` owns the preallocated contact buffers of one solver and records its launches into
the solver's frame (so a CUDA graph captures them); it also evaluates the penetration metrics.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import find_active, keep_near
from physhand_mj.contact.objects import Objects
from physhand_mj.contact.query import apply_contact, decide_and_project
from physhand_mj.metrics import penetration_samples
from physhand_mj.types import Config, Model, Placement

KEEP_BELOW = 1.0e-5  # m: after a pass, triangles whose decision point is this close stay for the next


class Contact:
    """Skin-object contact for a solver ``Model`` against ``objects`` (see Config.contact*)."""

    capturable = True

    def __init__(self, model: Model, objects: Objects, config: Config):
        if objects.device != model.device:
            raise ValueError(f"objects live on {objects.device}, the model on {model.device}")
        d = model.device
        self.model, self.objects, self.config = model, objects, config
        n_tris = model.skin_faces.shape[0]
        self.n_tris = n_tris
        self.active = wp.zeros(max(n_tris, 1), dtype=int, device=d)
        self.active_count = wp.zeros(1, dtype=int, device=d)
        self.active_mask = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # near-geom bits per active slot
        self.active2 = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # ping-pong list between passes
        self.active2_mask = wp.zeros(max(n_tris, 1), dtype=int, device=d)
        self.active2_count = wp.zeros(1, dtype=int, device=d)
        self.delta = wp.zeros(model.n_vertices, dtype=wp.vec3, device=d)
        self.hits = wp.zeros(model.n_vertices, dtype=float, device=d)
        self.decision = wp.zeros(max(n_tris, 1), dtype=wp.vec4, device=d)
        self.push = wp.zeros(model.n_vertices, dtype=float, device=d)  # m, summed over the frame
        self.vertex_obj = wp.full(model.n_vertices, -1, dtype=int, device=d)
        self.metrics = wp.zeros((config.substeps + 1, 3), dtype=float, device=d)
        self._metrics_host = wp.zeros((config.substeps + 1, 3), dtype=float, device="cpu",
                                      pinned=wp.get_device(d).is_cuda)

    # -- recording into the solver's frame --------------------------------------------------------
    def wants(self, stage: str) -> bool:
        p = self.config.contact_placement
        return (stage == "before" and p in (Placement.BEFORE, Placement.BOTH)) or (
            stage == "after" and p in (Placement.AFTER, Placement.BOTH))

    def record(self, launch, ops: list, state) -> None:
        """Broadphase once, then ``contact_passes`` x (decision points + Eq. 9, averaged apply); after
        each pass only triangles whose decision point came within KEEP_BELOW of an object stay in
        the list (penetrating ones, and touching ones that a neighbour's correction can push in)."""
        m, o, cfg = self.model, self.objects, self.config
        if not self.n_tris:
            return
        ops.append(self.active_count.zero_)
        launch(find_active, self.n_tris, [m.skin_faces, state.x, o.gtype, o.size, o.pose, o.radius, o.mesh, o.count,
                                          cfg.contact_margin],
               [self.active, self.active_mask, self.active_count])
        lists = [(self.active, self.active_mask, self.active_count), (self.active2, self.active2_mask, self.active2_count)]
        for p in range(cfg.contact_passes):
            cur, nxt = lists[p % 2], lists[(p + 1) % 2]
            launch(decide_and_project, self.n_tris,
                   [m.skin_faces, o.gtype, o.size, o.pose, o.radius, o.mesh, o.count, o.obj, cur[0], cur[1], cur[2],
                    int(cfg.contact), cfg.multires_samples, cfg.multires_rounds, cfg.opt_queries, state.x],
                   [self.delta, self.hits, self.decision, self.vertex_obj])
            launch(apply_contact, m.n_vertices, [self.delta, self.hits], [state.x, self.push])
            if p + 1 < cfg.contact_passes:
                ops.append(nxt[2].zero_)
                launch(keep_near, self.n_tris, [cur[0], cur[1], cur[2], self.decision, KEEP_BELOW],
                       [nxt[0], nxt[1], nxt[2]])

    def begin_frame(self, ops: list) -> None:
        """Reset the per-frame report buffers (metrics, push, touched object)."""
        ops += [self.metrics.zero_, self.push.zero_, lambda: self.vertex_obj.fill_(-1)]

    def record_metrics(self, launch, state, row: int, obj: int = -1, out=None) -> None:
        m, o = self.model, self.objects
        if self.n_tris:
            launch(penetration_samples, self.n_tris,
                   [m.skin_faces, state.x, o.gtype, o.size, o.pose, o.radius, o.mesh, o.count, o.obj, obj, row],
                   [self.metrics if out is None else out])

    # -- host side ---------------------------------------------------------------------------------
    def run_stage(self, state) -> np.ndarray:
        """Run one contact stage now (broadphase + passes) on ``state.x``; returns (F, 4) decision
        points of the last pass (x*, phi(x*)) with phi = FAR for triangles the broadphase skipped.
        For tests and diagnostics: inside a frame the solver records the same launches."""
        ops: list = []
        d = self.model.device

        def launch(kernel, dim, inputs, outputs):
            if dim:
                ops.append(lambda: wp.launch(kernel, dim, inputs=inputs, outputs=outputs, device=d))

        ops.append(lambda: self.decision.fill_(wp.vec4(0.0, 0.0, 0.0, 1.0e6)))
        self.record(launch, ops, state)
        for op in ops:
            op()
        wp.synchronize_device(d)
        return self.decision.numpy()[: self.n_tris].copy()

    def copy_metrics(self) -> None:
        """Start the device-to-host copy of the metrics (the caller synchronises once per frame)."""
        wp.copy(self._metrics_host, self.metrics)

    def read_metrics(self, synchronize: bool = True) -> np.ndarray:
        """(substeps + 1, 3) [count, sum depth m, max depth m]; the last row is the frame's end.
        Rows of substeps are zero unless Config.substep_metrics."""
        if synchronize:
            self.copy_metrics()
            wp.synchronize_device(self.metrics.device)
        return self._metrics_host.numpy().copy()
