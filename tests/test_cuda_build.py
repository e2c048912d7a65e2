"""CUDA builds checked without a GPU: Warp bundles NVRTC, so a kernel that will not compile for the
GPU machine (an H100, sm_90) fails here, before a device session spends its time finding out."""

import pytest
import warp as wp

pytestmark = pytest.mark.slow  # NVRTC compiles the big modules for sm_90 each run (~4-9 s a module)


def _nvrtc_archs():
    wp.init()
    from warp._src.context import runtime

    return getattr(runtime, "nvrtc_supported_archs", None) or set()


@pytest.mark.skipif(90 not in _nvrtc_archs(), reason="Warp's NVRTC cannot target sm_90 here")
def test_the_feature_kernels_build_for_an_h100(tmp_path):
    """contact/features.py (the object side's lists and pushes), contact/slack.py (Config.tuning.feature_slack's
    frame check: skin_motion, skin_reach, certify_features, next_slack) and contact/winding.py (the
    patches, sized per point) build to sm_90 machine code."""
    from physhand_mj.contact import features, slack, winding

    for module in (features, slack, winding):
        out = wp.compile_aot_module(module, arch=90, module_dir=tmp_path / module.__name__, use_ptx=False)
        assert out and all(p.exists() and p.stat().st_size > 0 for p in out)


@pytest.mark.skipif(90 not in _nvrtc_archs(), reason="Warp's NVRTC cannot target sm_90 here")
def test_the_geom_set_kernels_build_for_an_h100(tmp_path):
    """The kernels that take the objects' geoms as one struct (sdf.GeomSet) and the flag-made
    variants (broadphase.list_source, metrics.penetration_source, inside.points_inside_source) build
    to sm_90 machine code: contact/broadphase.py, query.py (and its MULTIRES and tiled decision-point
    kernels), linear.py, metrics.py and inside.py."""
    from physhand_mj.contact import broadphase, inside, linear, metrics, query, query_tiled

    modules = [broadphase, query, linear, metrics, inside, query.multires_kernel(128).module,
               query_tiled.tiled_kernel_for(True).module, query_tiled.tiled_kernel_for(False).module]
    for i, module in enumerate(modules):
        out = wp.compile_aot_module(module, arch=90, module_dir=tmp_path / str(i), use_ptx=False)
        assert out and all(p.exists() and p.stat().st_size > 0 for p in out)


@pytest.mark.skipif(90 not in _nvrtc_archs(), reason="Warp's NVRTC cannot target sm_90 here")
def test_the_self_contact_kernels_build_for_an_h100(tmp_path):
    """solver/self_contact.py (the query, the passes' launches, the fold rule's normals) and
    solver/self_slack.py (the query slack) build to sm_90 machine code."""
    from physhand_mj.solver import self_contact, self_slack

    for i, module in enumerate((self_contact, self_slack)):
        out = wp.compile_aot_module(module, arch=90, module_dir=tmp_path / str(i), use_ptx=False)
        assert out and all(p.exists() and p.stat().st_size > 0 for p in out)
