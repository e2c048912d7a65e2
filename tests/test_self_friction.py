"""Coulomb friction between touching parts of the skin (Config.tuning.self_friction,
self_contact.pair_correction): a vertex-triangle pair's slip along the triangle within a substep is
undone up to mu x the pair's normal correction (analytic cases on one pair), the x_prev share stays
the normal correction's, and a closing hand with friction stays finite and penetration-free."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.solver.self_contact import pair_correction

THICK = 5.0e-4  # m: Tuning.self_thickness's default


@wp.kernel
def _one_pair(x: wp.array(dtype=wp.vec3), x_prev: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float),
              faces: wp.array2d(dtype=int), mu: float, vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
              tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float), out: wp.array(dtype=wp.vec3),
              moved: wp.array(dtype=int)):
    moves, a, b, c, dv, da, db, dc, fr, fv, fa, fb, fc = pair_correction(3, 0, 0, 0, 0, x, inv_mass, faces, THICK,
                                                                         5.0e-3, 0.0, mu, vt_off, vt, tets, vol0, x_prev)
    moved[0] = moves
    # (the moves applied: normal + friction; the x_prev parts: the normal moves' share fr)
    out[0] = dv + fv
    out[1] = da + fa
    out[2] = db + fb
    out[3] = dc + fc
    out[4] = fr * dv
    out[5] = fr * da
    out[6] = fr * db
    out[7] = fr * dc


DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


def _pair(mu: float, slide: float, gap: float = 2.0e-4, gap0: float = 6.0e-4, masses=(1.0, 1.0, 1.0, 1.0), device="cpu",
          carry=(0.0, 0.0)):
    """Triangle (0, 1, 2) in the z = 0 plane (normal +z), vertex 3 ``gap`` m in front of it, having slid
    ``slide`` m along x over the substep from ``gap0`` m in front, while the triangle moved by ``carry``
    (m, along x and y); returns (moves (4, 3), x_prev parts (4, 3), positions after, positions before,
    x_prev)."""
    tri = np.array([[0.0, 0.0, 0.0], [1e-2, 0.0, 0.0], [0.0, 1e-2, 0.0]])
    x = np.vstack([tri, [2e-3, 2e-3, gap]])
    xp = np.vstack([tri - [carry[0], carry[1], 0.0], [2e-3 - slide - carry[0], 2e-3 - carry[1], gap0]])
    d = device
    out = wp.zeros(8, dtype=wp.vec3, device=d)
    moved = wp.zeros(1, dtype=int, device=d)
    wp.launch(_one_pair, 1, inputs=[wp.array(x, dtype=wp.vec3, device=d), wp.array(xp, dtype=wp.vec3, device=d),
                                    wp.array(np.asarray(masses, np.float32), dtype=float, device=d),
                                    wp.array(np.array([[0, 1, 2]], np.int32), dtype=int, device=d), float(mu),
                                    wp.zeros(1, dtype=int, device=d), wp.zeros(1, dtype=int, device=d),
                                    wp.zeros((1, 4), dtype=int, device=d), wp.zeros(1, dtype=float, device=d)],
              outputs=[out, moved], device=d)
    assert moved.numpy()[0] == 1
    o = out.numpy().astype(float)
    # (order of the moves: vertex 3, then the corners 0, 1, 2)
    moves = np.vstack([o[1:4], o[0]])
    prev = np.vstack([o[5:8], o[4]])
    return moves, prev, x + moves, x, xp


def _slip(after, xp):
    """The vertex's slip along the triangle against the triangle's point under it (barycentrics of
    (2, 2) mm on the 10 mm triangle: 0.6, 0.2, 0.2), over the substep, tangential part (m)."""
    bary = np.array([0.6, 0.2, 0.2])
    rel = (after[3] - xp[3]) - (bary @ after[:3] - bary @ xp[:3])
    return rel - np.array([0.0, 0.0, 1.0]) * rel[2]


def test_frictionless_pair_keeps_its_slip():
    """mu = 0: the normal correction only (along the normal), the slip stays 1 mm."""
    moves, prev, after, _, xp = _pair(0.0, 1.0e-3)
    np.testing.assert_allclose(moves[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(_slip(after, xp), [1.0e-3, 0.0, 0.0], atol=1e-9)
    # the vertex ends self_thickness in front of the triangle (the hard correction)
    bary = np.array([0.6, 0.2, 0.2])
    assert after[3, 2] - bary @ after[:3, 2] == pytest.approx(THICK, abs=1e-9)


def test_sticking_pair_undoes_its_slip():
    """A slip within mu x the normal correction (0.3 mm, mu 10: 3 mm) is undone: the vertex ends at
    rest on the triangle's point, the normal correction unchanged."""
    moves0, *_ = _pair(0.0, 1.0e-4)
    moves, prev, after, _, xp = _pair(10.0, 1.0e-4)
    np.testing.assert_allclose(_slip(after, xp), 0.0, atol=1e-9)
    np.testing.assert_allclose(moves[:, 2], moves0[:, 2], atol=1e-12)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("masses", [(1.0, 1.0, 1.0, 1.0), (0.5, 2.0, 1.0, 4.0)])
def test_sliding_pair_loses_mu_times_the_normal_correction(masses, device):
    """A slip beyond the bound is cut by exactly mu x the normal correction (3e-4 m of correction,
    mu 0.5: 0.15 mm off a 1 mm slip), along the slip, shared by the inverse masses (momentum: the
    moves weighted by mass sum to zero)."""
    moves, prev, after, _, xp = _pair(0.5, 1.0e-3, masses=masses, device=device)
    np.testing.assert_allclose(_slip(after, xp), [1.0e-3 - 0.5 * (THICK - 2.0e-4), 0.0, 0.0], atol=1e-9)
    m = 1.0 / np.asarray(masses)  # (masses of vertices 0-3: the corners, then the vertex, as the moves)
    np.testing.assert_allclose((m[:, None] * moves).sum(axis=0), 0.0, atol=1e-9)


def test_friction_acts_on_the_relative_slip():
    """The triangle moving with the vertex (both 2 mm along x and 1 mm along y over the substep, the
    vertex 1 mm further along x) is a 1 mm relative slip: cut by mu x the correction as on a still
    triangle; the common motion is no slip."""
    moves, prev, after, _, xp = _pair(0.5, 1.0e-3, carry=(2.0e-3, 1.0e-3))
    np.testing.assert_allclose(_slip(after, xp), [1.0e-3 - 0.5 * (THICK - 2.0e-4), 0.0, 0.0], atol=1e-9)
    moves, prev, after, _, xp = _pair(10.0, 0.0, carry=(2.0e-3, 1.0e-3))
    np.testing.assert_allclose(moves[:, :2], 0.0, atol=1e-9)  # (float32: the slip's rounding, ~1e-10 m)


def test_config_checks_friction():
    """self_friction must be a coefficient in [0, 2]."""
    ph.Config(self_collision=True, tuning=ph.Tuning(self_friction=0.5)).validate()
    for bad in (-0.1, float("nan"), 2.5):
        with pytest.raises(ValueError, match="self_friction"):
            ph.Config(self_collision=True, tuning=ph.Tuning(self_friction=bad)).validate()


def test_x_prev_takes_only_the_normal_share():
    """The pair came in from 0.6 mm in front (beyond self_thickness), so none of its correction moves
    x_prev; started 0.1 mm in front (the depth it had at the substep's start) the normal
    correction's share moves x_prev, along the normal only: friction changes the velocity."""
    _, prev, *_ = _pair(0.5, 1.0e-3)
    np.testing.assert_allclose(prev, 0.0, atol=1e-12)
    moves, prev, *_ = _pair(0.5, 1.0e-3, gap0=1.0e-4)
    assert np.abs(prev[:, 2]).max() > 0.0
    np.testing.assert_allclose(prev[:, :2], 0.0, atol=1e-12)
    assert np.abs(moves[:, 0]).max() > 0.0


def _rollout(key: str, device: str, frames: int):
    """``hand_only``'s keyframe ``key`` rolled out ``frames`` frames as ``physhand rollout`` does, with
    self-collision and self_friction 0.5; the hand and the last report."""
    import mujoco

    from physhand_mj.rollout import load_rollout_scene

    model, data, _ = load_rollout_scene(ph.scene_path("hand_only"), key)
    cfg = ph.Config(frame_dt=float(model.opt.timestep), device=device, self_collision=True,
                    tuning=ph.Tuning(self_friction=0.5))
    hand = ph.SoftHand(model, data, cfg, settle_contact=False)
    res = {}
    for _ in range(frames):
        mujoco.mj_step(model, data)
        res = hand.step()
    x = hand.state.x.numpy()
    assert np.all(np.isfinite(x)) and res["self_corrections"] > 0
    return hand, x


@pytest.mark.slow
def test_pinch_with_friction_stays_clean():
    """hand_only's pinch rolled out 36 frames with self_friction 0.5: finite, no skin vertex's 0.2 mm
    offset inside the closed skin (the independent measure), as without friction, and no more
    inverted tets than without it (23) but two."""
    from physhand_mj.contact.self_measures import self_penetration

    hand, x = _rollout("pinch", "cpu", 36)
    m = self_penetration(x, np.asarray(hand.asset.skin_faces), np.asarray(hand.asset.tets),
                         hand.solver.model.rest_x.numpy())
    assert m["inside_200um"] == 0 and m["inverted_tets"] <= 25


@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_power_with_friction_on_cuda():
    """The power grasp with self_friction 0.5 on CUDA (one hand: the five-launch substep and the
    passes as launches) for 12 frames: finite, pairs corrected, at most 100 vertices inside at 0.2 mm
    (the CPU: 28)."""
    from physhand_mj.contact.self_measures import self_penetration

    hand, x = _rollout("power", "cuda:0", 12)
    assert self_penetration(x, np.asarray(hand.asset.skin_faces))["inside_200um"] <= 100
