"""How kernels are launched: the device's name for reports, and the launch sizes of kernels that
walk a device-side list. Execution choices the code makes, never a user option."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import warp as wp


def device_name(device: str) -> str:
    """A human name for a Warp device: the GPU model, or the CPU model and core count."""
    d = wp.get_device(device)
    if d.is_cuda:
        return f"{d.alias} ({d.name})"
    model = platform.processor() or "cpu"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"cpu ({model}, {os.cpu_count()} cores, Warp CPU kernels single-threaded)"


# CUDA launches that walk a list whose length lives on the device (``count``; the tiled kernels' block
# per entry) are sized for the longest list (every skin triangle, every object feature point) and
# their threads past the list return at once; they run with at most this many blocks per SM, the
# kernels' grid-stride loop (Warp's default) walking the rest. A single hand's lists hold a few
# hundred to a few thousand entries of 10-20 thousand slots. Idle blocks are not free: on an H100 a
# graph node of 20,960 idle 32-thread blocks takes 13.9 us, capped at 8 per SM 6.3 us, against 1.5 us
# for 20,960 idle threads in 256-thread blocks (benchmarks/graph_node_cost.py, docs/activity.md).
# 0: no cap.
# Tiled kernels (a block per entry) of one warp (the decision points' 32 lanes) and of wider blocks
# (the feature kernels' 128 lanes) are capped apart.
LIST_BLOCKS_PER_SM = 8
TILED_BLOCKS_PER_SM = 8
WIDE_BLOCKS_PER_SM = 8


def list_launch_blocks(device, block_dim: int | None = None) -> int:
    """``max_blocks`` for a list-walking launch on ``device`` (``block_dim``: a tiled launch, a
    block of that many threads per entry); 0: as many as the launch asks."""
    d = wp.get_device(device)
    per_sm = LIST_BLOCKS_PER_SM if block_dim is None else TILED_BLOCKS_PER_SM if block_dim <= 32 else WIDE_BLOCKS_PER_SM
    return per_sm * d.sm_count if d.is_cuda and per_sm > 0 else 0


def tiled_blocks(device, n: int, block_dim: int) -> int:
    """Blocks of a tiled launch over a list of at most ``n`` entries whose kernel walks the list
    itself (its ``stride`` argument: block b takes entries b, b + stride, ... up to the count on the
    device): ``n``, on CUDA at most :func:`list_launch_blocks`. A block past the list's end reads
    the count and leaves; Warp's own grid-stride loop (``max_blocks`` over a launch of ``n``
    blocks) made every block walk all ``n`` slots, ~9 idle rounds a block on the held grasp's
    decision points, three quarters of that launch (Nsight Compute, docs/activity.md)."""
    cap = list_launch_blocks(device, block_dim)
    return max(1, min(int(n), cap) if cap else int(n))


def launch_options(device, count=None, block_dim: int | None = None) -> dict:
    """``wp.launch`` keywords of a recorded launch: ``block_dim`` for a tiled kernel, and on CUDA
    ``max_blocks`` (:func:`list_launch_blocks`) when it walks a device-side list (``count`` given, or
    tiled: a block per entry)."""
    kw = {} if block_dim is None else dict(block_dim=block_dim)
    if count is not None or block_dim is not None:
        cap = list_launch_blocks(device, block_dim)
        if cap:
            kw["max_blocks"] = cap
    return kw


class Recorder:
    """Where a stage records its work: :attr:`ops`, a list of zero-argument operations (launches,
    memsets, copies) run later in order. This one runs every block it is given (no gates) and
    records the frame's broadphase with the rest; the solver's
    :class:`~physhand_mj.solver.solver.FrameRecorder` gates blocks on the contact's work
    (physhand_mj/solver/activity.py), records the broadphase ahead of the frame on CUDA and makes
    its launches once their modules are compiled.

    A stage calls :meth:`launch` for a kernel, appends other ops to :attr:`ops`, and records a block
    that may be skipped through :meth:`gated` (whose ``record(ops)`` appends to the list it is given,
    which is :attr:`ops` meanwhile)."""

    def __init__(self, device, ops: list | None = None):
        self.device = device
        self.ops = [] if ops is None else ops
        self.ahead = None  # the list the frame's broadphase goes to (None: ops)

    def launch(self, kernel, dim, inputs, outputs, count=None, block_dim=None, min_dim=0) -> None:
        """Record a launch of ``dim`` threads (none for 0); ``count`` (a (1,) int array: the length of
        the list the kernel walks), ``block_dim`` (tiled kernels) and ``min_dim`` as
        :func:`launch_options` and the solver's list launches read them."""
        if dim:
            d = self.device
            kw = launch_options(d, count, block_dim)
            self.ops.append(lambda: wp.launch(kernel, dim, inputs=inputs, outputs=outputs, device=d, **kw))

    def launch_ahead(self, kernel, dim, inputs, outputs, **kw) -> None:
        """:meth:`launch` into :attr:`ahead` where it is set (the frame's broadphase run before the
        frame: its list length picks the frame's graph), else into :attr:`ops`."""
        if self.ahead is None:
            self.launch(kernel, dim, inputs, outputs, **kw)
            return
        saved, self.ops = self.ops, self.ahead
        try:
            self.launch(kernel, dim, inputs, outputs, **kw)
        finally:
            self.ops = saved

    def ahead_ops(self) -> list:
        """The list the frame's broadphase and its resets go to."""
        return self.ops if self.ahead is None else self.ahead

    def gated(self, record, level: int, slots=(), flag=None):
        """Record ``record(ops)`` into a block that runs only when the contact has work at ``level``
        (the solver's gates: activity.py); here it always runs, recorded in line. Returns the gate
        (None: no gate)."""
        record(self.ops)
        return None

    def run(self) -> None:
        """Run the recorded ops in order, each dropped once run (a launch kept would hold its arrays)."""
        while self.ops:
            self.ops.pop(0)()
