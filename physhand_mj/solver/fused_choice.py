"""When the fused substep runs (``Config.execution.fused_substep``; the kernel and its host side: solver/fused.py):
what a config allows, where CUDA batches take it by default (``cuda_auto``, from ``CUDA_AUTO_WAVES``
worlds per SM), and the solver's choice (``choose``). The kernel's switches are read from
solver/fused.py when asked, so a benchmark that changes them (``fused.SUM``, ``fused.BLOCK_DIM``)
changes the choice too."""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.solver import fused

# CUDA: Config.execution.fused_substep=None picks the fused substep for a batch of at least this many worlds
# per SM. A block holds one world and an SM one block (207 KB of shared memory), so a batch runs in
# ceil(W / SMs) waves; since the fixed-point sum (2026-11-27) a wave takes ~2.4-3.3 ms a frame on an
# H100, and from a quarter of the SMs on it beats the gathers' five launches, which grow with W. H100,
# no contact (benchmarks/fused_substep.py --worlds 8,...,198, interleaved, eleventh session): fused /
# gathers 0.45 x at W = 8, 0.69 x at 16, 0.94 x at 24, 1.20 x at 32, 1.42 x at 48, 1.90 x at 64, 2.95 x
# at 132; with a sphere pressing every hand (batch_throughput.py --objects, two runs each way) 0.75 x at
# 32, 1.18-1.20 x at 40, 1.07-1.40 x at 48, 1.30-1.51 x at 56, 1.35 x at 64, 1.99 x at 132. So 0.3
# worlds per SM (H100: W >= 40). (1.5 until then: set against the float-sum kernel, ~2.5 x slower.)
CUDA_AUTO_WAVES = 0.3


def config_allows(config) -> bool:
    """Whether ``config`` lets the fused substep run (the Jacobi scheme, one iteration, no region
    sleep, ``jacobi_gather`` not True); a scheme given by name counts as its enum."""
    from physhand_mj.enums import enum_field
    from physhand_mj.types import Scheme

    try:
        scheme = enum_field(Scheme, config.scheme, "scheme")
    except ValueError:
        return False  # (validate() names it)
    return scheme == Scheme.JACOBI and config.iterations == 1 and not config.region_sleep and not config.jacobi_gather


def asset_shared_bytes(asset, device) -> int:
    """:func:`fused.block_bytes` of one world of ``asset`` (movable vertices: those up to the last
    non-skeleton one), before any model is built."""
    from physhand_mj.types import Layer

    movable = np.flatnonzero(np.asarray(asset.layer) != Layer.SKELETON)
    n_soft = int(movable.max()) + 1 if movable.size else 0
    return fused.block_bytes(len(asset.layer), n_soft, device.is_cuda)


def cuda_auto(config, asset, worlds: int, device) -> bool:
    """Whether ``Config.execution.fused_substep=None`` takes the fused substep for a batch of ``worlds``
    worlds of ``asset`` on ``device``: CUDA, at least ``CUDA_AUTO_WAVES`` worlds per SM, a config
    that allows it, a world that fits a block's shared memory, and the measured kernel (``SUM``
    "scatter" at ``BLOCK_DIM`` ``CUDA_BLOCK``: the gather sum was slower than the gathers)."""
    return (bool(device.is_cuda) and config.fused_substep is None and worlds >= CUDA_AUTO_WAVES * device.sm_count
            and fused.SUM == "scatter" and fused.BLOCK_DIM == fused.CUDA_BLOCK and config_allows(config)
            and asset_shared_bytes(asset, device) <= device.max_shared_memory_per_block)


def choose(model, config, device) -> fused.FusedSubstep | None:
    """The solver's fused substep per ``Config.execution.fused_substep``: True builds it (ValueError naming the
    option where it cannot run: the Config's own checks, a body whose movable vertices do not come
    first, a world larger than a block's shared memory); None builds it on the CPU where it can run
    (:func:`config_allows`, a world that fits; on CUDA a batch resolves None itself: :func:`cuda_auto`);
    False: None."""
    want = config.fused_substep
    if want is False:
        return None
    if want is None:
        # (CUDA: a large batch asks for it with True, BatchedHands per cuda_auto; CPU blocks of many
        # lanes: correct, but neither bit for bit nor faster)
        if device.is_cuda or not config_allows(config) or getattr(wp.config, "enable_cpu_blocks", False):
            return None
        try:
            fz = fused.FusedSubstep(model, device)
        except ValueError:
            return None
        return fz if fz.fits(device)[0] else None
    fz = fused.FusedSubstep(model, device)
    ok, limit = fz.fits(device)
    if not ok:
        raise ValueError(f"Config.execution.fused_substep: a world needs {fz.shared_bytes(device)} bytes of shared memory, "
                         f"{device} allows {limit} a block; set fused_substep=False (or None)")
    return fz
