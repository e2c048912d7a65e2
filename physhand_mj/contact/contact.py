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
from physhand_mj.metrics import penetration_samples, summarize
from physhand_mj.types import Config, Model, Placement


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
        self.active2 = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # ping-pong list between passes
        self.active2_count = wp.zeros(1, dtype=int, device=d)
        self.delta = wp.zeros(model.n_vertices, dtype=wp.vec3, device=d)
        self.hits = wp.zeros(model.n_vertices, dtype=float, device=d)
        self.decision = wp.zeros(max(n_tris, 1), dtype=wp.vec4, device=d)
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
        each pass only triangles whose decision point came within a quarter of the margin of an
        object stay in the list (their neighbours' corrections can move them back into contact)."""
        m, o, cfg = self.model, self.objects, self.config
        if not self.n_tris:
            return
        ops.append(self.active_count.zero_)
        launch(find_active, self.n_tris, [m.skin_faces, state.x, o.gtype, o.size, o.pose, o.radius, o.mesh, o.count,
                                          cfg.contact_margin],
               [self.active, self.active_count])
        lists = [(self.active, self.active_count), (self.active2, self.active2_count)]
        for p in range(cfg.contact_passes):
            cur, nxt = lists[p % 2], lists[(p + 1) % 2]
            launch(decide_and_project, self.n_tris,
                   [m.skin_faces, o.gtype, o.size, o.pose, o.radius, o.mesh, o.count, cur[0], cur[1],
                    int(cfg.contact), cfg.multires_samples, cfg.multires_rounds, cfg.opt_queries, state.x],
                   [self.delta, self.hits, self.decision])
            launch(apply_contact, m.n_vertices, [self.delta, self.hits], [state.x])
            if p + 1 < cfg.contact_passes:
                ops.append(nxt[1].zero_)
                launch(keep_near, self.n_tris, [cur[0], cur[1], self.decision, 0.25 * cfg.contact_margin],
                       [nxt[0], nxt[1]])

    def record_metrics(self, launch, state, row: int) -> None:
        m, o = self.model, self.objects
        if self.n_tris:
            launch(penetration_samples, self.n_tris,
                   [m.skin_faces, state.x, o.gtype, o.size, o.pose, o.radius, o.mesh, o.count, row], [self.metrics])

    # -- host side ---------------------------------------------------------------------------------
    def read_metrics(self) -> np.ndarray:
        """(substeps + 1, 3) [count, sum depth m, max depth m]; the last row is the frame's end.
        Rows of substeps are zero unless Config.substep_metrics."""
        wp.copy(self._metrics_host, self.metrics)
        wp.synchronize_device(self.metrics.device)
        return self._metrics_host.numpy().copy()

    def frame_metrics(self, rows: np.ndarray) -> dict:
        return summarize(rows[-1])
