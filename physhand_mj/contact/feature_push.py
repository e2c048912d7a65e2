"""The object's side of a contact pass: one feature push (contact/features.py) recorded for the pass's
path (the CPU's BVH walk after a skin refit, CUDA's block per feature, CUDA batches' thread per
feature over its patch) and applied at once; a mixin of :class:`~physhand_mj.contact.contact.Contact`,
whose arrays it reads (``feat_stage``, the patches, ``delta`` ... ``vertex_obj``)."""

from __future__ import annotations

from physhand_mj.contact.features import feature_contact, feature_contact_scan, feature_contact_tiled, feature_inputs
from physhand_mj.contact.query import apply_contact
from physhand_mj.launch import tiled_blocks


class FeaturePush:
    """Contact's feature push: :meth:`_record_features` and the arguments its kernels share."""

    @property
    def last_push_offset(self) -> float:
        """The stand-off (m) of a stage's last feature push: Config.tuning.feature_last_offset, or
        feature_offset where that is None (read when a stage is recorded, as feature_offset is)."""
        cfg = self.config
        return float(cfg.feature_offset if cfg.feature_last_offset is None else cfg.feature_last_offset)

    def _record_features(self, rec, state, p, skin, feat_count, stamp) -> tuple:
        """The feature push of pass ``p`` (features.py): the stage's listed features against the skin
        as it is now, applied at once; returns the counter slot of the vertices it moved and that
        counter."""
        m, cfg = self.model, self.config
        if p and not self.tiled_features:  # (pass 0 sees the skin its stage's list was made on; CUDA's
            # scans read the skin's shifted copy, which apply_contact keeps current: no refit there)
            rec.ops.append(self._refit_op(self.volume(state, winding=False), feat_count))
        slot = self._slot
        feat_touched = self._counter()
        # the stage's last push (Config.tuning.feature_last: pass p == contact_passes) to its own, smaller stand-off
        off = self.last_push_offset if p == cfg.contact_passes else cfg.feature_offset
        if p == 0 and self.tiled_features:  # CUDA: pushed by the stage's feature-list launch (record)
            assert feat_touched.ptr == self._first_push.ptr, "the first pass's feature counter slot moved"
        elif self.feature_scan:  # CUDA batches: a thread per feature over its patch
            rec.launch(feature_contact_scan, self.points.n_features,
                   self._feature_inputs(state, self.feat_stage, feat_count, off, feat_touched), [])
        elif self.tiled_features:  # CUDA: a block per feature over its patch (or the frame's list)
            nb = tiled_blocks(m.device, self.points.n_features, self.feature_lanes)
            rec.launch(feature_contact_tiled, (nb, self.feature_lanes),
                   self._feature_inputs(state, self.feat_stage, feat_count, off, feat_touched, stride=nb), [],
                   block_dim=self.feature_lanes)
        else:
            rec.launch(feature_contact, self.points.n_features,
                   self._feature_inputs(state, self.feat_stage, feat_count, off, feat_touched, skin=skin), [],
                   count=feat_count)
        shift, shifted = self._apply_shift(state)
        rec.launch(apply_contact, m.n_vertices, [self.touched, feat_touched, stamp, self.delta, self.hits, shift],
               [state.x, self.push, self.moved, self.disp, self.pass_move, shifted], count=feat_touched)
        return slot, feat_touched

    def _feature_inputs(self, state, cand, cand_count, offset: float, touched_count, skin=None, stride: int = 0,
                        out=None, out_count=None) -> list:
        """A feature kernel's arguments (features.feature_inputs) over the features ``cand`` (the
        frame's list, or a stage's) on ``state``'s skin: pushed to ``offset`` (m) with the vertices
        counted in ``touched_count``; ``skin`` the refitted skin volume (the BVH search), ``stride``
        the tiled launch's blocks, ``out``/``out_count`` a stage's list."""
        m, o, cfg = self.model, self.objects, self.config
        return feature_inputs(m.skin_faces, self._query_x(state), cand, cand_count, self.points.pts, self.points.geom,
                              self._qp, cfg.contact_frame_margin, skin=skin.id if skin is not None else 0,
                              tris=self.cand, tri_count=self.cand_count, stride=stride, geom_obj=o.obj,
                              keep=cfg.contact_margin, near=self.near_query, eps=self.feature_eps, offset=offset,
                              max_step=cfg.contact_margin, pose0=o.pose, x0=state.x, winding=self._winding_args(),
                              side=self._side(), out=out, out_count=out_count,
                              push=(self.delta, self.hits, self.touched, touched_count, self.vertex_obj))

    def _winding_args(self) -> list:
        """The feature kernels' local-winding-number inputs (features.py): [on, slot, pool, start,
        length, far angle]; off: the feature list's arrays stand in (never read)."""
        if self.config.feature_winding:
            return [1, self.feat_slot, self.patch_pool, self.patch_start, self.patch_len, self.far_angle]
        return [0, self.feat, self.feat, self.feat, self.feat, self.feat_stage_float]

    def _side(self):
        """The CPU's per-stage sides of the listed features (features.stage_features)."""
        return self.feat_side if self.config.feature_winding else self.feat_stage_float
