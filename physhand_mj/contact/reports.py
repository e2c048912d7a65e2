"""The contact's host-side reports of a frame, a mixin of :class:`~physhand_mj.contact.contact.Contact`:
the device-to-host copies the frame's one sync waits for, and what they say (the stages' list
lengths, the listed feature points, a fused stage that stopped early). The buffers are Contact's.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.solver.solver import SolverError


class ContactReports:
    """Per-frame reports of a :class:`~physhand_mj.contact.contact.Contact` (which owns the buffers:
    ``metrics``, ``counters``, their host copies, the world and stage layout)."""

    def copy_metrics(self) -> None:
        """Start the device-to-host copy of the metrics and list lengths (the caller synchronises
        once per frame)."""
        wp.copy(self._metrics_host, self.metrics)
        wp.copy(self._counters_host, self.counters)
        if len(self.pass_move) and self._pass_move_host is not self.pass_move:  # (CUDA: the ops report's)
            wp.copy(self._pass_move_host, self.pass_move)
        if self.fused:
            wp.copy(self._stuck_host, self._stuck)
        if self.world_stage is not None:
            wp.copy(self._world_stage_host, self.world_stage)
        if self.feat is not None:
            wp.copy(self._feat_host, self.feat_count)
            if self.config.feature_winding:
                wp.copy(self._patch_used_host, self.patch_used)
            wp.copy(self._slack_host, self.slack_report)

    def raise_if_stuck(self) -> None:
        """After the frame's sync: raise when a fused stage's grid barrier gave up waiting for a block
        (stage.grid_sync: its blocks were not resident at once, e.g. another kernel held SMs), since
        that frame's contact did not run to the end."""
        if self.fused and self._stuck_host.numpy()[0]:
            self.stage_barrier.zero_()
            raise SolverError("contact: a fused stage's blocks did not all run at once (Config.fused_stage needs the "
                               "GPU's SMs to itself for a stage: no other kernel running beside it); this frame's "
                               "contact stopped early; use fused_stage=False")

    def features_listed(self) -> int:
        """Object feature points in the last frame's list (after the frame's sync); warns once when
        their patches (the local winding number's, winding.py) overflowed the pool: those points
        kept the pseudo-normal sign (one hand) or were not pushed (CUDA batches)."""
        if self.feat is None:
            return 0
        if self.config.feature_winding and not self._patch_warned:
            used = int(self._patch_used_host.numpy()[0])
            if used > self.patch_pool.shape[0] or used < 0:  # (< 0: the int32 counter wrapped past 2^31)
                import warnings

                self._patch_warned = True
                need = f"{used}" if used >= 0 else "over 2^31"
                warnings.warn(f"contact: the feature points' patches needed {need} entries, the pool holds "
                              f"{self.patch_pool.shape[0]} (PATCH_POOL_MAX in physhand_mj/contact/contact.py): the "
                              f"points past it kept the pseudo-normal sign (one hand) or were not pushed (CUDA "
                              f"batches); use fewer worlds per batch", RuntimeWarning, stacklevel=2)
        return int(self._feat_host.numpy()[0])

    def feature_motion(self, ran: bool = True) -> dict:
        """The last frame, worst world (after the frame's sync; Config.feature_slack, features.py):
        ``feature_slack_mm``, the slack its feature lists were made with (m -> mm), ``skin_motion_mm``,
        the skin's largest move in it, and ``feature_slack_exceeded``, the worlds in which a skin
        vertex moved far enough, near enough to a feature point, that the point's list or patch could
        have missed a skin triangle (warned about once where the lists had been cut short of
        contact_frame_margin). A frame that did not run its contact block (``ran`` False: nothing
        near) made no lists: its move and count are 0, its slack the last lists'. Empty without
        feature points."""
        if self.feat is None:
            return {}
        r = self._slack_host.numpy()
        if not ran:
            return dict(feature_slack_mm=round(float(r[:, 0].max()) * 1e3, 4), skin_motion_mm=0.0,
                        feature_slack_exceeded=0)
        over = int(np.count_nonzero(r[:, 2]))
        # (warned where the lists were cut short of contact_frame_margin: at it they are the frame
        # broadphase's own, as before the slack; the count says it either way)
        if over and not self._slack_warned and np.any(r[r[:, 2] > 0, 0] < self.config.contact_frame_margin):
            import warnings

            self._slack_warned = True
            w = int(np.flatnonzero(r[:, 2])[0])
            warnings.warn(f"contact: a skin vertex moved up to {r[w, 1] * 1e3:.2f} mm in one frame near an object's "
                          f"feature points, whose lists allowed for {r[w, 0] * 1e3:.2f} mm (Config.feature_slack): a "
                          f"point's patch could have missed a closer skin triangle in that frame; the next frame's "
                          f"lists allow for more; raise Config.feature_slack (m) for hands that move this fast",
                          RuntimeWarning, stacklevel=3)
        return dict(feature_slack_mm=round(float(r[:, 0].max()) * 1e3, 4),
                    skin_motion_mm=round(float(r[:, 1].max()) * 1e3, 4), feature_slack_exceeded=over)

    def feature_motion_worlds(self, ran: bool = True) -> list:
        """Per world, 1 where the last frame's feature-list check failed (:meth:`feature_motion`),
        else 0 (also in a frame whose contact block did not run); empty without feature points."""
        if self.feat is None:
            return []
        if not ran:
            return [0] * self.worlds
        return [int(v) for v in self._slack_host.numpy()[:, 2]]

    def stage_counts(self) -> np.ndarray:
        """(stages, 2) int of the last frame (after ``read_metrics``): per contact stage, the active
        triangles and the skin vertices its first pass corrected (in contact at the stage's start; Eq. 9's
        and the feature push's, a vertex both moved counted twice)."""
        c = self._counters_host.numpy()
        return np.array([[c[a], c[t] + (c[f] if f >= 0 else 0)] for a, t, f in self._stage_slots],
                        dtype=int).reshape(-1, 2)

    def stage_counts_worlds(self) -> np.ndarray:
        """(W, stages, 2) int: :meth:`stage_counts` per world (after the frame's sync; one world:
        the frame's own, (1, stages, 2))."""
        if self.world_stage is None:
            return self.stage_counts()[None]
        n = len(self._stage_slots)
        return self._world_stage_host.numpy().reshape(self.worlds, -1, 2)[:, :n].copy()
