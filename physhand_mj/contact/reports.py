"""The contact's host-side reports of a frame, a mixin of :class:`~physhand_mj.contact.contact.Contact`:
the device-to-host copies the frame's one sync waits for, and what they say (the stages' list
lengths, the listed feature points). The buffers are Contact's.
"""

from __future__ import annotations

import numpy as np
import warp as wp



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
        if self.world_stage is not None:
            wp.copy(self._world_stage_host, self.world_stage)
        if self.feat is not None:
            wp.copy(self._feat_host, self.feat_count)
            if self.config.feature_winding:
                wp.copy(self._patch_used_host, self.patch_used)
            wp.copy(self._slack_host, self.slack_report)  # (slack.py's report)

    def features_listed(self) -> int:
        """Object feature points in the last frame's list (after the frame's sync). Sizes the patch
        pool (the local winding number's, winding.py) for the frames to come: where the frame's
        patches needed more than half of it packed (what the BVH path is sure to fit) or did not fit,
        it grows to twice their need, up to PATCH_POOL_MAX, and the solver records its frames again
        (a frame that overflowed kept, for the points past the pool, the pseudo-normal sign (one
        hand) or pushed them not at all (CUDA batches)). An overflow at PATCH_POOL_MAX warns once."""
        if self.feat is None:
            return 0
        if self.config.feature_winding:
            self._fit_patch_pool()
        return int(self._feat_host.numpy()[0])

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
