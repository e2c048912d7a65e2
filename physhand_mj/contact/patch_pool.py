"""The local winding number's patch pool (contact/winding.py, contact/features.py): the skin triangles
near each listed object feature point (its patch), packed in one int32 pool per contact. How large it
starts (:func:`patch_pool_size`) and how it grows after a frame that needed more
(:func:`fit_patch_pool`, run by Contact.features_listed after the frame's sync; the solver then
records its frames again, ``Contact.reallocations``).
"""

from __future__ import annotations

import math

import warp as wp

# the local winding number's patch pool (features.py): entries per feature point of the objects,
# within [PATCH_POOL_MIN, PATCH_POOL_MAX] in all (the demo's listed features hold ~170 triangles each
# within 1 cm, at most ~270, and ~184 of its ~1,760 (features every 0.25 mm) are listed per frame); a
# patch that does not fit keeps the pseudo-normal sign (one hand) or is not pushed (CUDA batches) in
# that frame, after which the pool grows (:func:`fit_patch_pool`, from Contact.features_listed).
# 2^30 int32 entries (4 GiB) at most: the HOI box grasp at W = 4096 needs 442 M (an H100, 2026-11-26;
# with the 2^28 it had then, points of some worlds went unpushed, up to 0.49 mm inside)
# The BVH path (winding.feature_patches) gives the k-th of a frame's n listed features the slot
# pool[k c: (k + 1) c], c = min(PATCH_SLOT, pool // 2 n), and the larger patches room at the top (the
# other half at least): a pool of 2 x 128 entries per feature point holds in its top half every list
# the packed pool of 128 held, however many patches pass their slots (slots over the whole pool left
# the hard cases' deep starts no room: 47-267 points without a patch, tests/test_winding.py); at
# PATCH_POOL_MAX every patch is sure to fit while the list needs at most half of it packed
PATCH_SLOT = 128
PATCH_POOL_PER_FEATURE = 2 * PATCH_SLOT
PATCH_POOL_MIN = 1 << 15
PATCH_POOL_MAX = 1 << 30
# the frame margin PATCH_POOL_PER_FEATURE was measured at (the default): a patch's radius is at most
# Config.contact_frame_margin and the skin triangles within it grow with its square (the rest skin's,
# within a ball about a skin vertex: 147 on average at 10 mm, 500 at 20 mm, 1,074 at 30 mm), so a
# larger margin gets proportionally more entries per feature point, up to PATCH_POOL_SCALED (16 MiB;
# a large object's many feature points, most of them never listed, keep the unscaled pool); past
# that the pool grows when a frame needs more (Contact.features_listed). MyoSuite's 20 mm
# margin: the myoHandReorient envs list ~1,400 of 1,960 points, needing 449 k entries packed, past the
# 502 k of 256 per point (211 patches did not fit); 2.0 M with the margin's square
PATCH_POOL_MARGIN = 0.01
PATCH_POOL_SCALED = 1 << 22


def patch_pool_size(n_features: int, frame_margin: float) -> int:
    """The patch pool's first size (entries) for ``n_features`` object feature points (every
    world's) whose patches reach at most ``frame_margin`` (m): PATCH_POOL_PER_FEATURE each, times
    (frame_margin / PATCH_POOL_MARGIN)^2 above PATCH_POOL_MARGIN up to PATCH_POOL_SCALED in all,
    within [PATCH_POOL_MIN, PATCH_POOL_MAX]."""
    base = n_features * PATCH_POOL_PER_FEATURE
    scaled = math.ceil(base * max(1.0, (float(frame_margin) / PATCH_POOL_MARGIN) ** 2))
    return int(min(max(min(scaled, max(base, PATCH_POOL_SCALED)), PATCH_POOL_MIN), PATCH_POOL_MAX))


def fit_patch_pool(features, device, worlds: int, warned: bool) -> tuple[bool, bool]:
    """After a frame's sync: ``features``' (contact/data.FeatureLists) pool grown to a power of two at
    least twice the frame's need where its patches needed more than half of the pool packed or did not
    fit, up to PATCH_POOL_MAX; an overflow at PATCH_POOL_MAX warns once (``warned``: already, for
    ``worlds`` worlds). Returns (grown, warned)."""
    used, _, failed = (int(v) for v in features.patch_used_host.numpy())
    # (the BVH path counts the patches that did not fit; CUDA's tiled one packs them, full past the
    # pool's size; < 0: an int32 counter wrapped past 2^31)
    size = features.patch_pool.shape[0]
    over = bool(failed or used > size or used < 0)
    if size < PATCH_POOL_MAX and (over or 2 * used > size):
        # (a power of two at least twice the need and the pool: a list that keeps growing re-records rarely)
        grown = PATCH_POOL_MAX if used < 0 else min(1 << (max(2 * used, 2 * size) - 1).bit_length(), PATCH_POOL_MAX)
        features.patch_pool = wp.zeros(grown, dtype=int, device=device)
        features.patches.pool = features.patch_pool  # (the frames are recorded again)
        return True, warned
    if over and not warned:
        from physhand_mj.warn import warn_user

        need = f"{used:,}" if used >= 0 else "over 2^31"
        what = f"{failed} object feature points' patches did not fit: " if failed else ""
        per = f" ({worlds} worlds)" if worlds > 1 else ""
        warn_user(f"contact: {what}the feature points' patches (the skin triangles near each, for its inside "
                  f"test) needed {need} entries packed, more than the pool's most{per}, {size:,} (4 GiB): "
                  f"points past it kept the pseudo-normal sign (one hand) or were not pushed (CUDA batches). "
                  f"Run fewer worlds per BatchedHands, or a smaller Config.contact_frame_margin (the "
                  f"patches' radius)", RuntimeWarning)
        return False, True
    return False, warned
