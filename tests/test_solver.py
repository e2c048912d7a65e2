"""XPBD solver: analytic cases, physical invariants on the hand, guards, determinism, devices."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.solver.diagnostics import kinetic_energy, residuals, signed_volumes6
from physhand_mj.solver.model import signed_dihedral

DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])
VOLUME_TOL = 0.03  # relative change of the flesh volume allowed while the hand closes ("a few percent")


def _set_positions(state, x):
    state.x.assign(np.asarray(x, np.float32))
    state.x_prev.assign(np.asarray(x, np.float32))
    state.x_safe.assign(np.asarray(x, np.float32))


def _free_solver(body, device, **kw):
    cfg = ph.Config.from_dict(dict(device=device, gravity=(0.0, 0.0, 0.0), damping=0.0, **kw))
    solver = ph.Solver(ph.make_model(body, cfg), cfg)
    return solver, solver.make_state()


REST_TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 0.01  # 10 mm legs


@pytest.mark.parametrize("device", DEVICES)
def test_compressed_tet_recovers_rest_volume(device):
    body = ph.soft_body(REST_TET, tets=[[0, 1, 2, 3]])
    solver, state = _free_solver(body, device, edges=False)
    squashed = REST_TET.copy()
    squashed[3, 2] = 0.003  # 30 % of the rest volume
    _set_positions(state, squashed)
    for _ in range(20):
        solver.step(state)
    ratio = signed_volumes6(state.x.numpy().astype(float), body.tets)[0] / (6 * body.tet_rest_volume[0])
    assert abs(ratio - 1) < 1e-3, f"volume ratio {ratio:.5f} after 20 frames"


@pytest.mark.parametrize("device", DEVICES)
def test_stiffer_tet_recovers_faster(device):
    body = ph.soft_body(REST_TET, tets=[[0, 1, 2, 3]])
    errors = []
    for compliance in (1e-2, 1e-4):  # 1/Pa: bulk modulus 100 Pa vs 10 kPa
        solver, state = _free_solver(body, device, edges=False, volume_compliance=compliance)
        squashed = REST_TET.copy()
        squashed[3, 2] = 0.005
        _set_positions(state, squashed)
        solver.step(state)
        errors.append(abs(signed_volumes6(state.x.numpy().astype(float), body.tets)[0] / (6 * body.tet_rest_volume[0]) - 1))
    assert errors[1] < 0.5 * errors[0], f"volume error after one frame: soft {errors[0]:.4f}, stiff {errors[1]:.4f}"


@pytest.mark.parametrize("device", DEVICES)
def test_stretched_edge_converges_to_rest_length(device):
    x = np.array([[0.0, 0, 0], [0.01, 0, 0]])
    body = ph.soft_body(x, edges=[[0, 1]], vertex_mass=1e-3)
    solver, state = _free_solver(body, device, edge_compliance_skin=0.0)
    _set_positions(state, [[0.0, 0, 0], [0.02, 0, 0]])
    for _ in range(5):
        solver.step(state)
    y = state.x.numpy().astype(float)
    length = np.linalg.norm(y[1] - y[0])
    assert abs(length - 0.01) < 1e-6, f"edge length {length * 1e3:.5f} mm, rest 10 mm"
    assert np.allclose(y.mean(0), [0.01, 0, 0], atol=1e-6), "equal masses: the midpoint must stay put"


def test_dihedral_angle_and_gradient_match_numpy():
    from physhand_mj.solver.smooth import dihedral_angle_gradients

    @wp.kernel
    def eval_dihedral(q: wp.array2d(dtype=wp.vec3), theta: wp.array(dtype=float), grad: wp.array2d(dtype=wp.vec3)):
        i = wp.tid()
        t, g0, g1, g2, g3 = dihedral_angle_gradients(q[i, 0], q[i, 1], q[i, 2], q[i, 3])
        theta[i] = t
        grad[i, 0] = g0
        grad[i, 1] = g1
        grad[i, 2] = g2
        grad[i, 3] = g3

    rng = np.random.default_rng(3)
    quads = rng.normal(size=(64, 4, 3)) * 0.01
    theta = wp.zeros(64, dtype=float, device="cpu")
    grad = wp.zeros((64, 4), dtype=wp.vec3, device="cpu")
    wp.launch(eval_dihedral, 64, inputs=[wp.array(quads.astype(np.float32), dtype=wp.vec3, device="cpu")],
              outputs=[theta, grad], device="cpu")
    flat = quads.reshape(-1, 3)
    ids = np.arange(256).reshape(64, 4)
    ref = signed_dihedral(flat, ids)
    assert np.abs(theta.numpy() - ref).max() < 2e-6, "angle off the numpy atan2 reference"
    eps, fd = 1e-7, np.zeros_like(quads)
    for v in range(4):
        for k in range(3):
            d = np.zeros_like(quads)
            d[:, v, k] = eps
            fd[:, v, k] = (signed_dihedral((quads + d).reshape(-1, 3), ids) - signed_dihedral((quads - d).reshape(-1, 3), ids)) / (2 * eps)
    g = grad.numpy()
    scale = np.abs(fd).max(axis=(1, 2), keepdims=True)
    assert np.abs(g - fd).max(axis=(1, 2)).max() / scale.min() < 1e-3, "gradient differs from finite differences"
    assert np.abs(g.sum(axis=1)).max() < 1e-3 * scale.max(), "gradients must sum to zero (translation invariance)"


def test_signed_rest_angles_match_the_assets_arccos(asset):
    signed = signed_dihedral(asset.positions, asset.dihedral)
    assert np.allclose(np.abs(signed), asset.dihedral_rest_angle, atol=1e-6)


# -- the hand ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def hand():
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    return asset, model, data, ph.body_ids(model, asset.body_names)


def _run_hand(hand, frames, qpos_at=None, device="cpu", keep=(), **kw):
    """The hand palm down (hand_only scene) for ``frames`` frames; bones at ``qpos_at(frame)``. The
    log rows of the frames (0-based) in ``keep`` also hold the positions after that frame ("x")."""
    asset, model, data, ids = hand
    cfg = ph.Config.from_dict(dict(device=device, **kw))
    solver = ph.Solver(ph.make_model(asset, cfg), cfg)
    q_open = model.key("open").qpos.copy()
    poses = ph.bone_poses_at(model, data, q_open, ids)
    state = solver.make_state(*ph.mount_pose(model, data))
    x0 = state.x.numpy().astype(float)
    log = []
    for f in range(frames):
        if qpos_at is not None:
            poses = ph.bone_poses_at(model, data, qpos_at(f), ids)
        solver.set_body_poses(state, *poses)
        guard = solver.step(state)
        log.append(dict(guard, ke=kinetic_energy(solver.model, state, asset.mass),
                        volume=signed_volumes6(state.x.numpy().astype(float), asset.tets).sum() / 6))
        if f in keep:
            log[-1]["x"] = state.x.numpy().astype(float)
    return solver, state, x0, log


@pytest.fixture(scope="module")
def under_gravity(hand):
    """Config()'s hand palm down under gravity, bones fixed open, for 120 frames (the positions kept
    after frame 60): settling, and Fig. 6's full model (the CPU runs are deterministic, so its 60
    frames are this run's first 60)."""
    return _run_hand(hand, 120, keep=(59,))


def test_skeleton_follows_its_bones_exactly(hand):
    asset, model, data, ids = hand
    q = model.key("pinch").qpos.copy()
    solver, state, _, _ = _run_hand(hand, 3, lambda f: q)
    pos, quat = ph.bone_poses_at(model, data, q, ids)
    from physhand_mj.rotations import quat_to_mat
    skel = np.flatnonzero(asset.layer == ph.Layer.SKELETON)
    b = asset.vertex_body[skel]
    rest_rot = quat_to_mat(asset.body_rest_quat)
    local = np.einsum("kji,kj->ki", rest_rot[b], asset.positions[skel] - asset.body_rest_pos[b])
    expected = np.einsum("kij,kj->ki", quat_to_mat(quat)[b], local) + pos[b]
    err = np.abs(state.x.numpy()[skel] - expected).max()
    assert err < 1e-6, f"skeleton vertices off their bones by {err * 1e6:.2f} um"


def test_hand_settles_under_gravity(under_gravity):
    _, _, _, log = under_gravity
    ke = np.array([r["ke"] for r in log])
    assert ke[-10:].mean() < 0.02 * ke.max(), f"kinetic energy {ke[-10:].mean():.2e} J vs peak {ke.max():.2e} J"
    assert all(r["nonfinite"] == 0 and r["inverted"] == 0 for r in log)


def test_fig6_ablation_attachment_and_smoothness(hand, under_gravity):
    """Paper Fig. 6 in numbers: hand palm down under gravity, bones fixed in the open pose, 60 frames."""
    asset = hand[0]
    rest = signed_dihedral(asset.positions, asset.dihedral)
    out = {}
    for name, kw in {"a": dict(attachment=False, smoothness=False), "b": dict(smoothness=False), "c": None}.items():
        if kw is None:  # the full model: frame 60 of the settling run
            x0, x = under_gravity[2], under_gravity[3][59]["x"]
        else:
            _, state, x0, _ = _run_hand(hand, 60, **kw)
            x = state.x.numpy().astype(float)
        flesh = asset.layer == ph.Layer.FLESH
        dev = signed_dihedral(x, asset.dihedral) - rest
        out[name] = (np.linalg.norm(x - x0, axis=1)[flesh].mean(), np.sqrt(np.mean(dev ** 2)))
    assert out["b"][0] < 0.8 * out["a"][0], f"attachment should firm the flesh: sag {out['a'][0]:.2e} -> {out['b'][0]:.2e} m"
    assert out["c"][1] < 0.8 * out["b"][1], f"smoothness should keep dihedrals: {out['b'][1]:.4f} -> {out['c'][1]:.4f} rad"


def test_grasp_keeps_volume_and_recovers(hand):
    """Close to the power fist in 50 frames, hold, open again: volume within a few percent, no NaN;
    tets inverted at the deep flexion creases (docs/solver.md) are few and all recover at rest."""
    asset, model, _, _ = hand
    q_open, q_power = model.key("open").qpos.copy(), model.key("power").qpos.copy()

    def closing(f):
        a = min(1.0, (f + 1) / 50) if f < 70 else max(0.0, 1 - (f - 69) / 50)
        return q_open + a * (q_power - q_open)

    solver, state, x0, log = _run_hand(hand, 140, closing)
    v0 = asset.tet_rest_volume.sum()
    change = max(abs(r["volume"] / v0 - 1) for r in log)
    assert change < VOLUME_TOL, f"volume changed by {change:.2%}"
    assert all(r["nonfinite"] == 0 for r in log)
    n_tets = solver.model.guard_tets.shape[0]
    worst = max(r["inverted"] for r in log)
    assert worst < 0.015 * n_tets, f"{worst} of {n_tets} tets inverted at the fist"
    assert log[-1]["inverted"] == 0, "tets must recover once the hand is open again"
    back = np.abs(state.x.numpy() - x0).max()
    assert back < 2e-3, f"open again, the hand is {back * 1e3:.2f} mm off its rest shape"


def test_results_are_deterministic_on_cpu(hand):
    asset, model, _, _ = hand
    q_open, q_pinch = model.key("open").qpos.copy(), model.key("pinch").qpos.copy()
    runs = [_run_hand(hand, 8, lambda f: q_open + (f + 1) / 8 * (q_pinch - q_open))[1].x.numpy() for _ in range(2)]
    assert np.array_equal(runs[0], runs[1])


def test_colouring_separates_movable_vertices(asset):
    model = ph.make_model(asset, ph.Config(device="cpu", tuning=ph.Tuning(scheme=ph.Scheme.COLORED)))
    movable = model.inv_mass.numpy() > 0
    for name, ids in (("edge", model.edge_ids), ("tet", model.tet_ids), ("dih", model.dih_ids)):
        ids = ids.numpy()
        for start, end in model.colors[name]:
            v = ids[start:end].ravel()
            v = v[movable[v]]
            assert len(np.unique(v)) == len(v), f"{name} colour [{start}, {end}) shares a movable vertex"


@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
@pytest.mark.parametrize("scheme", [ph.Scheme.JACOBI, ph.Scheme.COLORED])
def test_cpu_and_cuda_agree(hand, scheme):
    """Same frames on both devices. Jacobi through a pinch closing; coloured Gauss-Seidel, whose
    single-pass overshoot amplifies float rounding differences under fast motion (docs/solver.md),
    under gravity with the bones still."""
    asset, model, _, _ = hand
    q_open, q_pinch = model.key("open").qpos.copy(), model.key("pinch").qpos.copy()
    moving = scheme == ph.Scheme.JACOBI
    xs = {}
    for device in ("cpu", "cuda"):
        solver, state, _, _ = _run_hand(hand, 20, (lambda f: q_open + min(1, (f + 1) / 15) * (q_pinch - q_open))
                                        if moving else None, device=device, scheme=scheme)
        xs[device] = state.x.numpy().astype(float)
        if device == "cuda":
            assert solver._graphs, "the CUDA frame should run as a captured graph"
    err = np.abs(xs["cpu"] - xs["cuda"]).max()
    assert err < 2e-5, f"CPU and CUDA differ by {err * 1e6:.2f} um"


def test_gather_lists_name_each_vertex_slots_in_order():
    """solver/gather.py's CSR lists on a hand-made group: two families (2 edges; 1 tet), vertex 3
    kinematic. Every movable vertex lists exactly the slots that hold its corrections, ascending."""
    from physhand_mj.solver.gather import gather_lists

    edges = np.array([[0, 1], [1, 2]])
    tets = np.array([[2, 0, 3, 1]])
    movable = np.array([True, True, True, False])
    off, slots, bases = gather_lists([edges, tets], movable)
    assert bases == [0, 4]  # the tet's slots follow the 4 edge slots
    rows = [slots[off[i]:off[i + 1]].tolist() for i in range(4)]
    # slot = base + corner * rows + row (corner-major), listed in constraint order (row, corner):
    # vertex 1 is edge 0's corner 1 (slot 2), then edge 1's corner 0 (1), then the tet's corner 3 (7)
    assert rows == [[0, 5], [2, 1, 7], [3, 4], []]


@pytest.mark.parametrize("device", DEVICES)
def test_jacobi_gather_repeats_and_matches_the_atomics(hand, device):
    """Config.execution.jacobi_gather: the constraints' corrections summed per vertex in a fixed order. On the
    CPU that is the atomic result bit for bit (threads run in order there); on CUDA two runs repeat
    bit for bit and stay within float rounding of the atomic run."""
    asset, model, _, _ = hand
    q_open, q_pinch = model.key("open").qpos.copy(), model.key("pinch").qpos.copy()
    close = lambda f: q_open + min(1, (f + 1) / 6) * (q_pinch - q_open)  # noqa: E731
    xs = {}
    for name, gather in (("atomics", False), ("gather", True), ("gather again", True)):
        solver, state, _, log = _run_hand(hand, 8, close, device=device, jacobi_gather=gather, sleep_speed=0.0)
        assert bool(solver.model.gather_off) == gather and all(g["nonfinite"] == 0 for g in log)
        if gather:  # the constraints did write their slots (not the atomic path under another name)
            assert np.abs(state.corr.numpy()).max() > 0 and not np.any(state.delta.numpy())
        xs[name] = state.x.numpy()
    assert np.array_equal(xs["gather"], xs["gather again"])
    if device == "cpu":
        assert np.array_equal(xs["gather"], xs["atomics"])
    else:
        assert np.abs(xs["gather"] - xs["atomics"]).max() < 5e-6
    with pytest.raises(ValueError, match="jacobi_gather"):
        ph.Config(execution=ph.Execution(jacobi_gather="yes")).validate()


# -- guards and errors ----------------------------------------------------------------------------

def test_nan_vertex_is_recovered_and_counted():
    body = ph.soft_body(REST_TET, tets=[[0, 1, 2, 3]])
    solver, state = _free_solver(body, "cpu")
    solver.step(state)
    x = state.x.numpy().copy()
    x[2] = np.nan
    state.x.assign(x)
    guard = solver.step(state)
    assert guard["nonfinite"] >= 1
    assert np.all(np.isfinite(state.x.numpy())), "NaN must not survive the frame"
    for _ in range(3):
        assert solver.step(state)["nonfinite"] == 0
    assert np.all(np.isfinite(state.x.numpy()))


def test_nan_under_raise_policy_raises():
    body = ph.soft_body(REST_TET, tets=[[0, 1, 2, 3]])
    solver, state = _free_solver(body, "cpu", nonfinite=ph.NonFinite.RAISE)
    x = state.x.numpy().copy()
    x[0] = np.inf
    state.x.assign(x)
    with pytest.raises(ph.SolverError, match="non-finite"):
        solver.step(state)


def test_bad_bone_poses_are_rejected(hand):
    asset, model, data, ids = hand
    cfg = ph.Config(device="cpu")
    solver = ph.Solver(ph.make_model(asset, cfg), cfg)
    state = solver.make_state()
    pos, quat = ph.bone_poses_at(model, data, model.key("open").qpos, ids)
    pos[3, 1] = np.nan
    with pytest.raises(ph.SolverError, match=str(asset.body_names[3])):
        solver.set_body_poses(state, pos, quat)
    with pytest.raises(ValueError, match="bone poses must be"):
        solver.set_body_poses(state, pos[:5], quat)
    with pytest.raises(ValueError, match="qpos must be"):
        ph.bone_poses_at(model, data, np.full(model.nq, np.nan), ids)


@pytest.mark.parametrize("field,value", [("substeps", 0), ("frame_dt", -1.0), ("gravity", (0, 0)),
                                         ("volume_compliance", float("nan")), ("relaxation", 2.5),
                                         ("contact", "nne"), ("contact", 7), ("scheme", "gauss")])
def test_config_errors_name_the_option(field, value):
    with pytest.raises(ValueError, match=rf"Config\.(tuning\.|execution\.)?{field}"):
        ph.Config.from_dict({field: value}).validate()


def test_config_enums_take_members_numbers_and_names():
    """Config's enum fields take the member, its number or its name in any case (JSON configs on the
    command line: --config '{"contact": "none"}'); a wrong one lists the choices."""
    for value in (ph.Strategy.NONE, 0, "none", "NONE"):
        assert ph.Config(contact=value).validate().contact is ph.Strategy.NONE
    assert ph.Config(contact="multires").validate().contact is ph.Strategy.MULTIRES
    with pytest.raises(ValueError, match="NONE \\(0\\), VERTEX \\(1\\), OPT \\(2\\), MULTIRES \\(3\\)"):
        ph.Config(contact="sdf").validate()


def test_residual_falls_with_iterations(hand):
    """More constraint passes per substep solve the constraints better (XPBD residual)."""
    asset, model, data, ids = hand
    q = model.key("open").qpos + 0.3 * (model.key("power").qpos - model.key("open").qpos)
    res = []
    for iterations in (1, 16):
        cfg = ph.Config(device="cpu", substeps=1, frame_dt=5e-4, iterations=iterations)
        solver = ph.Solver(ph.make_model(asset, cfg), cfg)
        ph.bone_poses_at(model, data, model.key("open").qpos, ids)
        state = solver.make_state(*ph.mount_pose(model, data))
        solver.set_body_poses(state, *ph.bone_poses_at(model, data, q, ids))
        solver.step(state)
        res.append(residuals(solver.model, state, cfg)["all"])
    assert res[1] < 0.6 * res[0], f"residual after 1 and 16 iterations: {res}"
