"""The CUDA multires kernel: a block per active skin triangle, a lane per lattice sample.

:func:`decide_and_project_tiled` is query.decide_and_project's MULTIRES for CUDA (Config.execution.tiled_contact):
each of the block's TILE_LANES lanes queries one sample of Algorithm 2's lattice, block reductions
pick the three lowest, lane 0 projects (Eq. 9, query.project). The serial chain per triangle shrinks
from samples x rounds queries to rounds x (1 query + 3 reductions); the samples, rounds, early-out,
bound and projection are the per-thread kernel's.
"""

import functools

import warp as wp

from physhand_mj.contact.query import decide_source

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

TILE_LANES = 32  # lanes per triangle in the CUDA multires kernel (>= the lattice's sample count)


@functools.cache  # (one kernel a flag: a second one in the same module would change its hash)
def tiled_kernel(with_mesh: bool):
    """:func:`decide_and_project_tiled` over the geom SDFs with the MESH branch (``with_mesh``) or
    without it (:func:`tiled_kernel_for`): query.decide_source's tiled variant, launched with
    ``stride`` blocks (launch.tiled_blocks) of TILE_LANES threads; block b takes entries b, b +
    stride, ... of the list and a block past its end reads the count and leaves (Warp's own
    grid-stride loop over every slot cost the held grasp's launch ~9 idle rounds a block,
    docs/activity.md). Arguments: query.decide_inputs."""
    fn = decide_source(True, True, with_mesh)
    # the kernels' own names (Nsight Compute, cpu_op_split.py), not the factory's
    fn.__name__ = fn.__qualname__ = "decide_and_project_tiled" + ("" if with_mesh else "_analytic")
    if with_mesh:
        return wp.kernel(fn, module=__name__)
    k = wp.kernel(fn, module=f"{__name__}_analytic", enable_backward=False)
    k.module.options["block_dim"] = TILE_LANES
    return k


decide_and_project_tiled = tiled_kernel(True)
decide_and_project_tiled_analytic = tiled_kernel(False)  # (its own module: compiled only where a scene uses it)


def tiled_kernel_for(has_mesh: bool):
    """The CUDA multires kernel for a scene with a mesh geom or without: without, the kernel
    compiled without the MESH branch (sdf.geom_sdf_funcs), 114 registers a thread and no spills on
    sm_90 against 255 and a 640 B spill frame (`python benchmarks/aot_cache.py --resources decide`).
    The same answers for every analytic geom; a mesh geom would read FAR in it, so the solver records
    its frames again when a geom is added after they were recorded (Solver._recorded_geoms)."""
    return decide_and_project_tiled if has_mesh else decide_and_project_tiled_analytic
