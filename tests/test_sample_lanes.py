"""Config.sample_lanes (contact/query_lanes.py): the multires decision points with a lane per
lattice sample take query.decide_triangle's operations in its order, so a batch pressed by a sphere
and a mesh box ends with the per-thread kernel's skins bit for bit on the CPU, with the scratch
holding every entry or only a few (the rest run whole per thread); the lattice's lanes and points
are Algorithm 2's; bad values are refused."""

import numpy as np
import pytest
import warp as wp

import physhand_mj.contact.query_lanes as lanes_mod
from physhand_mj.contact.query import lattice_order
from physhand_mj.contact.query_lanes import lattice_lanes, lattice_point
from physhand_mj.types import Config
from tests.test_multires_kernel import _pressed_batch


@pytest.mark.parametrize("samples, rounds, cap", [(21, 2, None), (21, 2, 4), (16, 3, 64)],
                         ids=["scratch for all", "4 entries, the rest per thread", "centroid lane, 3 rounds, 64 entries"])
def test_lanes_press_as_the_per_thread_kernel(monkeypatch, samples, rounds, cap):
    if cap is not None:  # the entries past the scratch run the per-thread decide, after the lanes' (the list's order)
        monkeypatch.setattr(lanes_mod, "LANES_MIN_CAP", cap)
        monkeypatch.setattr(lanes_mod, "LANES_SHARE", 0.0)
    made = []
    real = lanes_mod.SampleLanes

    class Spy(real):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    import physhand_mj.contact.contact as contact_mod
    monkeypatch.setattr(contact_mod, "SampleLanes", Spy)
    kw = dict(multires_samples=samples, multires_rounds=rounds)
    before, thread, out = _pressed_batch(sample_lanes=False, **kw)
    assert not made
    _, lanes, out2 = _pressed_batch(sample_lanes=True, **kw)
    assert made and made[0].lanes == lattice_lanes(samples)[1]
    if cap is not None:
        assert made[0].cap == cap and out2["triangles_tested"] > 3 * cap  # entries past the scratch had work
    else:
        assert made[0].cap == made[0].tri.shape[0] >= out2["triangles_tested"] / 3
    assert np.abs(thread - before).max() > 1e-3, "nothing pressed the hands: the test would compare nothing"
    assert out["triangles_tested"] == out2["triangles_tested"] > 4
    np.testing.assert_array_equal(lanes, thread)
    assert out["penetration_count"] == out2["penetration_count"] == 0


@wp.kernel
def _points(ta: wp.vec3, tb: wp.vec3, tc: wp.vec3, order: int, out: wp.array(dtype=wp.vec3)):
    s = wp.tid()
    out[s] = lattice_point(ta, tb, tc, s, order, 1.0 / float(order))


@wp.kernel
def _order(samples: wp.array(dtype=int), out: wp.array(dtype=int)):
    i = wp.tid()
    out[i] = lattice_order(samples[i])


@pytest.mark.parametrize("samples", [3, 6, 10, 16, 21, 28, 31])
def test_lanes_are_the_lattice_in_its_order(samples):
    order, lanes = lattice_lanes(samples)
    got = wp.zeros(1, dtype=int)
    wp.launch(_order, 1, [wp.array([samples], dtype=int)], [got])
    assert order == int(got.numpy()[0])  # the host's order is the kernel's
    n = (order + 1) * (order + 2) // 2
    assert lanes == n + (n < samples) and lanes <= samples
    ta, tb, tc = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 2.0, 0])
    out = wp.zeros(lanes, dtype=wp.vec3)
    wp.launch(_points, lanes, [wp.vec3(*ta), wp.vec3(*tb), wp.vec3(*tc), order], [out])
    want = [ta * (1 - i / order - j / order) + tb * i / order + tc * j / order
            for i in range(order + 1) for j in range(order + 1 - i)]
    if lanes > n:
        want.append((ta + tb + tc) / 3)
    np.testing.assert_allclose(out.numpy(), np.array(want), atol=1e-6)


@pytest.mark.parametrize("bad", [1, 0, "yes", None])
def test_bad_lane_settings_are_refused(bad):
    with pytest.raises(ValueError, match="sample_lanes"):
        Config(sample_lanes=bad).validate()
