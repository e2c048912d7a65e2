"""Config.execution.fused_substep (physhand_mj/solver/fused.py): a substep's three Jacobi groups in one
shared-memory launch per world give the five-launch solver's positions: bit for bit on the CPU
(one lane per block, the constraints in the atomic path's order), within float rounding of the
sum's order on CUDA."""

import numpy as np
import pytest
import warp as wp

from physhand_mj.config import Execution, Tuning
import physhand_mj as ph
from physhand_mj.batch import BatchedHands
from physhand_mj.types import GeomType
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
from physhand_mj.solver import Solver, fused_choice, make_model
from physhand_mj.types import Config, Layer, Scheme

DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])
# CUDA: the shared-memory atomics (and the five-launch reference's global ones) add a vertex's
# corrections in no fixed order; after 8 frames of a bending finger the two runs differ by float
# rounding grown over 80 substeps (two atomic CUDA runs differ by ~0.4 um after a closing: docs/solver.md)
CUDA_TOL = 5.0e-6  # m


@pytest.fixture(scope="module")
def setup():
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    q0 = model.key("open").qpos.copy()
    q1 = q0.copy()
    q1[model.jnt_qposadr[model.joint("mcp2_flexion_r").id]] += 0.6
    open_, bent = (bone_poses_at(model, data, q, ids) for q in (q0, q1))
    return asset, mount_pose(model, data), open_, bent


def _run(asset, mount, open_, bent, cfg, worlds=2, frames=8):
    batch = BatchedHands(asset, worlds, cfg, *mount)
    out = None
    for f in range(frames):
        a = min((f + 1) / 4, 1.0)
        poses = [open_] + [(bent[0] * a + open_[0] * (1 - a), bent[1])] * (worlds - 1)
        out = batch.step(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]))
        assert out["nonfinite"] == 0
    return batch, out


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("sum_", ["scatter", "gather"])
def test_fused_substep_equals_the_five_launch_substep(setup, device, sum_, monkeypatch):
    """Two worlds (one held open, one bending its index finger): the fused substep's positions are
    the default solver's (bit for bit on the CPU; on CUDA within the rounding of the reference's
    own float atomics), and it records fewer launches. Summed by vertex ("gather") a CUDA run
    repeats bit for bit (a fixed order, no atomics)."""
    from physhand_mj.solver import fused

    monkeypatch.setattr(fused, "SUM", sum_)
    asset, mount, open_, bent = setup
    # (jacobi_gather off: on CUDA a batch gathers by default and then stores its tets in Morton
    # order, so the tet multipliers would come in another row order than the fused run's)
    ref, ref_out = _run(asset, mount, open_, bent, Config(device=device, execution=Execution(fused_substep=False, jacobi_gather=False)))
    fz, fz_out = _run(asset, mount, open_, bent, Config(device=device, execution=Execution(fused_substep=True)))
    assert fz.solver._fused is not None and ref.solver._fused is None
    assert fz_out["ops_run"] < ref_out["ops_run"] - 3 * Config().substeps, (fz_out["ops_run"], ref_out["ops_run"])
    for w in range(2):
        diff = np.abs(fz.positions(w) - ref.positions(w)).max()
        if device == "cpu":
            assert diff == 0.0, f"world {w}: {diff} m from the five-launch substep"
        else:
            assert diff <= CUDA_TOL, f"world {w}: {diff} m from the five-launch substep (tolerance {CUDA_TOL})"
    if device == "cpu":  # (no objects: the fused run takes a frame's substeps in one launch, FRAME_LAUNCH)
        assert fz.solver._fused.frame_launch and fz_out["ops_run"] < ref_out["ops_run"] - 5 * Config().substeps
        for name in ("v", "x_prev", "x_safe", "guard"):  # (each substep's start, made inside that launch)
            assert np.array_equal(getattr(fz.state, name).numpy(), getattr(ref.state, name).numpy()), name
    for name in ("lam_edge", "lam_tet", "lam_dih"):  # the multipliers of the last substep (diagnostics read them)
        a, b = getattr(fz.state, name).numpy(), getattr(ref.state, name).numpy()
        if device == "cpu":
            assert np.array_equal(a, b), name
        else:
            assert np.abs(a - b).max() <= 1e-3 * np.abs(b).max(), name
    if device != "cpu":  # (CUDA's five-launch reference adds in the atomics' order; the gather and the
        # fixed-point scatter, ACCUM "auto" on CUDA, add in no order that shows)
        again, _ = _run(asset, mount, open_, bent, Config(device=device, execution=Execution(fused_substep=True)))
        for w in range(2):
            assert np.array_equal(again.positions(w), fz.positions(w)), f"world {w}: the {sum_} did not repeat"
    moved = np.abs(fz.positions(1) - fz.positions(0)).max()
    assert moved > 1e-3, moved  # the worlds differ: each block solved its own world


@pytest.mark.parametrize("placement", ["after", "both"])
def test_fused_substep_with_contact_and_one_hand(setup, placement):
    """One hand held open, and a batch whose world 1 has a sphere pressed 2 mm into the back of
    its hand (the contact stages run between the fused launches; with a stage before the
    constraints the substep's start stays a launch of its own): the same positions as the
    default solver, bit for bit on the CPU, and nothing inside the sphere at the end."""
    asset, mount, open_, bent = setup
    skins = []
    for fused in (False, None):  # None: the CPU's default, fused
        cfg = Config(device="cpu", execution=Execution(fused_substep=fused))
        solver = Solver(make_model(asset, cfg), cfg)
        assert (solver._fused is None) == (fused is False)
        state = solver.make_state(*mount)
        for _ in range(3):
            solver.set_body_poses(state, *open_)
            solver.step(state)
        skins.append(state.x.numpy())
    assert np.array_equal(skins[0], skins[1])
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
    runs = []
    for fused in (False, True):
        batch = BatchedHands(asset, 2, Config(device="cpu", tuning=Tuning(contact_placement=placement), execution=Execution(fused_substep=fused)), *mount,
                             objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
        skin = batch.skin(0)
        top = skin[np.argmax(skin[:, 2])].astype(float)
        where = np.stack([top + [0.0, 0.1, 0.05], top + [0.0, 0.0, 0.02 - 0.002]])[:, None]
        for _ in range(3):
            out = batch.step(np.stack([open_[0]] * 2), np.stack([open_[1]] * 2), where, ident)
        assert out["penetration_count"] == 0 and out["triangles_tested"] > 0, out
        runs.append(batch)
    for w in range(2):
        assert np.array_equal(runs[0].positions(w), runs[1].positions(w))
    for name in ("v", "x_prev", "x_safe", "guard", "lam_edge", "lam_tet", "lam_dih"):  # (the substep's start, folded
        # into the launch or not; the multipliers, written in the last substep's launch)
        assert np.array_equal(getattr(runs[0].state, name).numpy(), getattr(runs[1].state, name).numpy()), name
    assert np.abs(runs[1].skin(1) - runs[1].skin(0)).max() > 1e-3  # world 1 was pressed


@pytest.mark.parametrize("bad", [dict(iterations=2), dict(scheme=Scheme.COLORED), dict(region_sleep=True),
                                 dict(fused_substep=1)])
def test_fused_substep_refuses_what_it_cannot_run(bad):
    kw = dict(fused_substep=True)
    kw.update(bad)
    with pytest.raises(ValueError, match="fused_substep"):
        Config.from_dict(dict(device="cpu", **kw)).validate()


@pytest.mark.parametrize("kw", [dict(iterations=2), dict(scheme=Scheme.COLORED), dict(jacobi_gather=True),
                                dict(region_sleep=True)])
def test_default_falls_back_where_the_fused_substep_cannot_run(setup, kw):
    """``fused_substep=None`` (the default) fuses on the CPU only where it can: otherwise the
    five-launch substep, with no error."""
    asset = setup[0]
    cfg = Config.from_dict(dict(device="cpu", **kw))
    solver = Solver(make_model(asset, cfg), cfg)
    assert solver._fused is None
    default = Config(device="cpu")
    assert Solver(make_model(asset, default), default)._fused is not None


class _H100:
    """What cuda_auto reads of a CUDA device: an H100's SMs and a block's shared memory."""
    is_cuda = True
    sm_count = 132
    max_shared_memory_per_block = 232_448


def test_cuda_batches_take_the_fused_substep_from_a_third_of_a_world_per_sm(setup):
    """On CUDA ``fused_substep=None`` takes the fused substep for a batch of at least 0.3 worlds
    per SM (fused_choice.CUDA_AUTO_WAVES; H100: 40), not below, not where the config or a block's shared
    memory rules it out, and never on the CPU (which decides per solver, above)."""
    from physhand_mj.solver import fused

    asset, h100 = setup[0], _H100()
    assert fused_choice.asset_shared_bytes(asset, h100) == 207_504 + 4 * fused.BLOCK_DIM
    cfg = Config().validate()
    assert not fused_choice.cuda_auto(cfg, asset, 39, h100)
    assert fused_choice.cuda_auto(cfg, asset, 40, h100) and fused_choice.cuda_auto(cfg, asset, 4096, h100)
    for kw in (dict(jacobi_gather=True), dict(iterations=2), dict(scheme=Scheme.COLORED), dict(region_sleep=True),
               dict(fused_substep=False)):
        assert not fused_choice.cuda_auto(Config.from_dict(kw).validate(), asset, 4096, h100), kw
    assert fused_choice.cuda_auto(Config(tuning=Tuning(scheme="jacobi")).validate(), asset, 4096, h100)  # (a scheme by name)
    small = _H100()
    small.max_shared_memory_per_block = 100_000  # (a card whose block cannot hold a world)
    assert not fused_choice.cuda_auto(cfg, asset, 4096, small)
    assert not fused_choice.cuda_auto(cfg, asset, 4096, wp.get_device("cpu"))
    fused_sum = fused.SUM
    try:  # (only the measured kernel: the by-vertex sum ran slower than the gathers)
        fused.SUM = "gather"
        assert not fused_choice.cuda_auto(cfg, asset, 4096, h100)
    finally:
        fused.SUM = fused_sum


@pytest.mark.skipif(not wp.is_cuda_available(), reason="needs CUDA")
def test_a_large_cuda_batch_runs_the_fused_substep_by_default(setup):
    """A BatchedHands of fused_choice.CUDA_AUTO_WAVES worlds per SM on the GPU resolves ``fused_substep=None``
    to the fused substep (no per-vertex gather slots built), and a small batch (2 worlds) keeps the gathers."""
    import math

    asset, mount = setup[0], setup[1]
    sms = wp.get_device("cuda").sm_count
    big = BatchedHands(asset, math.ceil(fused_choice.CUDA_AUTO_WAVES * sms), Config(device="cuda"), *mount)
    assert big.solver.fused_substep and big.config.fused_substep is True
    assert not big.solver.model.gather_off
    big.close()
    small = BatchedHands(asset, 2, Config(device="cuda"), *mount)
    assert not small.solver.fused_substep and small.config.fused_substep is None
    small.close()


@pytest.mark.parametrize("sum_, order, accum, mass", [("scatter", "asset", "float", "vertex"),
                                                    ("gather", "asset", "float", "row"),
                                                    ("scatter", "strided", "float", "row"),
                                                    ("scatter", "asset", "fixed", "row")])
def test_fused_kernel_compiles_for_hopper_and_fits_a_block(setup, tmp_path, sum_, order, accum, mass, monkeypatch):
    """The CUDA kernel is built ahead of time here (Warp's NVRTC; no GPU needed) for sm_90, down to
    the cubin (so the native snippets' inline PTX is assembled too), and the
    embedded hand's world fits one H100/H200 block: its dynamic shared memory (positions and soft
    corrections) within the 227 KB a block may hold, less 4 KB for the scatter's scratch."""
    from physhand_mj.solver import fused

    monkeypatch.setattr(fused, "SUM", sum_)
    monkeypatch.setattr(fused, "ORDER", order)
    monkeypatch.setattr(fused, "ACCUM", accum)  # (the CPU's "auto" is float)
    monkeypatch.setattr(fused, "MASS", mass)
    asset = setup[0]
    cfg = Config(device="cpu", execution=Execution(fused_substep=True))
    fz = fused.FusedSubstep(make_model(asset, cfg), "cpu")
    assert fz.fixed == (accum == "fixed" and sum_ == "scatter") and fz.row_mass == (mass == "row")
    assert fz.n == asset.n_vertices and fz.n_soft == int((np.asarray(asset.layer) != Layer.SKELETON).sum())
    kernel = fz.kernel
    kernel.module.options["block_dim"] = fused.BLOCK_DIM
    try:
        wp.compile_aot_module(kernel.module, device=None, arch=90, module_dir=str(tmp_path), use_ptx=False)
    except Exception as e:  # noqa: BLE001 - a Warp build without NVRTC cannot build CUDA code here
        if "NVRTC" in str(e) or "nvrtc" in str(e):
            pytest.skip(f"no NVRTC in this Warp build: {e}")
        raise
    import json

    meta = json.loads(next(tmp_path.glob("*.meta")).read_text())
    smem = next(v for k, v in meta.items() if k.endswith("forward_smem_bytes"))
    assert smem == fz.shared_bytes(), (smem, fz.shared_bytes())  # (tiles 16-byte aligned)
    assert smem + 4096 <= 227 * 1024, f"{smem} bytes of shared memory a block: over an H100's 227 KB"


def test_a_body_too_large_for_a_block_falls_back_or_is_refused(setup, monkeypatch):
    """Warp's CPU arena (256 KiB) and a GPU block bound what a world may take: past it the default
    keeps the five-launch substep and ``fused_substep=True`` raises a ValueError naming the option,
    before any launch (on the CPU an oversized tile aborts the process)."""
    from physhand_mj.solver import fused

    asset = setup[0]
    monkeypatch.setattr(fused, "CPU_ARENA", 200_000)  # below the embedded hand's 207,504 bytes
    cpu = wp.get_device("cpu")
    for flag, expect in ((None, None), (False, None)):
        cfg = Config(device="cpu", execution=Execution(fused_substep=flag))
        assert fused_choice.choose(make_model(asset, cfg), cfg.validate(), cpu) is expect
    cfg = Config(device="cpu", execution=Execution(fused_substep=True))
    with pytest.raises(ValueError, match="fused_substep.*207504 bytes"):
        Solver(make_model(asset, cfg), cfg)
    cfg = Config(device="cpu", tuning=Tuning(scheme="jacobi"), execution=Execution(fused_substep=True))  # (a scheme given by name)
    assert cfg.validate().scheme == Scheme.JACOBI


@pytest.mark.parametrize("sum_", ["scatter", "gather"])
def test_fused_substep_with_blocks_of_many_lanes_on_the_cpu(setup, monkeypatch, sum_):
    """A GPU block's lanes on the CPU: with ``wp.config.enable_cpu_blocks`` Warp runs a tiled
    kernel's block as 64 lanes (fibers) meeting at its barriers, so each lane's share of the loops
    and the phases between barriers run here as on a GPU (the one-lane CPU default cannot see a
    lane-indexing error: one that gave the load loop's lanes the same entries passed the one-lane
    test and failed this one). The positions are the five-launch substep's within float rounding of
    the sum's order. Not caught here: a barrier inside a branch (Warp's element assignment to a
    shared tile, this path's first bug), which the CPU's fibers tolerate."""
    from physhand_mj.solver import fused

    asset, mount, open_, bent = setup
    if not hasattr(wp.config, "enable_cpu_blocks"):
        pytest.skip("this Warp has no multi-lane CPU blocks (wp.config.enable_cpu_blocks)")
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    monkeypatch.setattr(fused, "BLOCK_DIM", 64)  # (its own kernel: the 1,024-thread one stays one lane)
    monkeypatch.setattr(fused, "SUM", sum_)
    ref, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=False)), frames=4)
    fz, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=True)), frames=4)
    tol = 0.0 if sum_ == "gather" else 1e-6  # (by vertex: the same order whatever the lanes)
    for w in range(2):
        diff = np.abs(fz.positions(w) - ref.positions(w)).max()
        assert diff <= tol, f"world {w}: {diff} m from the five-launch substep with 64-lane blocks"
    lam, lam_ref = fz.state.lam_tet.numpy(), ref.state.lam_tet.numpy()
    assert np.abs(lam - lam_ref).max() <= (0.0 if sum_ == "gather" else 1e-4 * np.abs(lam_ref).max())


def test_strided_rows_spread_a_warp_over_the_family():
    """ORDER "strided"'s permutation: every constraint exactly once, and the 32 rows a warp walks
    together ~C / 32 apart."""
    from physhand_mj.solver.fused import FusedSubstep

    for count in (0, 1, 31, 32, 33, 1000, 47378):
        rows = FusedSubstep.strided_rows(count)
        assert np.array_equal(np.sort(rows), np.arange(count)), count
    rows = FusedSubstep.strided_rows(1000)
    assert np.all(np.diff(rows[:32]) == 32)  # (ceil(1000 / 32) = 32 apart)


@pytest.mark.parametrize("lanes", [1, 64])
def test_fused_substep_in_strided_order(setup, monkeypatch, lanes):
    """ORDER "strided" (the families permuted so that a warp's lanes take far-apart constraints):
    the five-launch substep's positions within float rounding of the sum's order, and each
    multiplier written to its asset row (a wrong row map would scramble them), with one lane and
    with Warp's 64-lane CPU blocks."""
    from physhand_mj.solver import fused

    asset, mount, open_, bent = setup
    if lanes > 1:
        if not hasattr(wp.config, "enable_cpu_blocks"):
            pytest.skip("this Warp has no multi-lane CPU blocks (wp.config.enable_cpu_blocks)")
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
        monkeypatch.setattr(fused, "BLOCK_DIM", 64)
    ref, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=False)), frames=4)
    monkeypatch.setattr(fused, "ORDER", "strided")
    fz, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=True)), frames=4)
    assert fz.solver._fused._strided is not None  # (the permuted families ran)
    for w in range(2):
        diff = np.abs(fz.positions(w) - ref.positions(w)).max()
        assert diff <= 1e-6, f"world {w}: {diff} m from the five-launch substep"
    for name in ("lam_edge", "lam_tet", "lam_dih"):  # (as the CUDA comparison: 1e-3 of the largest)
        a, b = getattr(fz.state, name).numpy(), getattr(ref.state, name).numpy()
        assert np.abs(a - b).max() <= 1e-3 * np.abs(b).max(), name


@pytest.mark.parametrize("lanes", [1, 64])
def test_fixed_point_sum_is_the_same_bits_in_any_order(setup, monkeypatch, lanes):
    """ACCUM "fixed" (CUDA's default): each correction rounded to 2^-28 m and added as int32, so a
    world's sum is exact and its bits do not depend on the order the lanes add in: one lane and 64
    lanes (Warp's CPU blocks), with the masses per vertex or per constraint, the rest data and the
    ids loaded either way, and a frame's substeps in one launch or one each, give the same positions
    and multipliers bit for bit; and they stay within 2 um of the float sum (the five-launch
    substep's bits on the CPU) after 4 frames of a bending finger."""
    from physhand_mj.solver import fused

    asset, mount, open_, bent = setup
    if lanes > 1 and not hasattr(wp.config, "enable_cpu_blocks"):
        pytest.skip("this Warp has no multi-lane CPU blocks (wp.config.enable_cpu_blocks)")
    ref, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=False)), frames=4)
    monkeypatch.setattr(fused, "ACCUM", "fixed")
    block = fused.BLOCK_DIM  # (the one-lane run's kernel: the default block's)

    def run(mass, loads, frame, k):
        monkeypatch.setattr(fused, "MASS", mass)
        monkeypatch.setattr(fused, "PIN_LOADS", loads)
        monkeypatch.setattr(fused, "VEC_LOADS", loads)
        monkeypatch.setattr(fused, "FRAME_LAUNCH", frame)
        if hasattr(wp.config, "enable_cpu_blocks"):
            monkeypatch.setattr(wp.config, "enable_cpu_blocks", k > 1)
        monkeypatch.setattr(fused, "BLOCK_DIM", 64 if k > 1 else block)
        batch, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=True)), frames=4)
        fz = batch.solver._fused
        assert fz.fixed and fz.row_mass == (mass == "row") and fz.frame_launch == frame
        assert fz._vec_ok() == (loads and mass == "row") and fz.pin == loads  # (what the kernel got)
        return batch

    one = run("row", True, True, 1)
    combos = [("vertex", False, False), ("row", False, True)] + ([("row", True, True)] if lanes > 1 else [])
    for mass, loads, frame in combos:
        batch = run(mass, loads, frame, lanes)
        for w in range(2):
            assert np.array_equal(batch.positions(w), one.positions(w)), (mass, loads, frame, lanes, w)
        for name in ("lam_edge", "lam_tet", "lam_dih", "v", "x_prev"):
            assert np.array_equal(getattr(batch.state, name).numpy(), getattr(one.state, name).numpy()), name
    for w in range(2):
        diff = np.abs(one.positions(w) - ref.positions(w)).max()
        assert 0.0 < diff <= 2e-6, f"world {w}: {diff} m from the float sum"


def test_fixed_point_bound_keeps_every_vertex_sum_in_int32(setup):
    """FusedSubstep's clamp: in each group a movable vertex receives at most vertex_count[g] of it
    corrections (counted here from the group's ids, corner by corner), each at most fx_bounds[g] x
    2^FIXED_BITS steps, so its sum stays under int32's 2^31; the bounds still pass any physical
    correction (10 cm in one substep)."""
    from physhand_mj.solver import fused

    cfg = Config(device="cpu", execution=Execution(fused_substep=True))
    fz = fused.FusedSubstep(make_model(setup[0], cfg), "cpu")
    counts = fz.vertex_count.numpy()
    for g, ids in enumerate((fz.edge_ids, fz.tet_ids, fz.dih_ids)):
        corners = ids.numpy().ravel()
        adds = np.bincount(corners[corners < fz.n_soft], minlength=fz.n_soft)[: fz.n_soft]
        assert np.all(adds <= counts[g, : fz.n_soft]), g  # (the premise of the bound)
        assert counts[g].max() * fz.fx_bounds[g] * fz.fx_scale < 2.0 ** 31, g
        assert fz.fx_bounds[g] > 0.1, g
    assert fz.fx_scale == 2.0 ** fused.FIXED_BITS


def test_fixed_point_add_rounds_clamps_and_drops_nan():
    """shared_add_fixed on its own (a one-lane CPU block): a correction adds round(v 2^28) per
    component, one past the bound adds the bound, and a NaN component adds nothing (a clamped NaN
    would push the constraint's finite corners by the bound)."""
    from physhand_mj.solver import fused_tile

    @wp.kernel(enable_backward=False)
    def probe(vals: wp.array(dtype=wp.vec3), slot: wp.array(dtype=int), out: wp.array(dtype=wp.vec3i), scale: float,
              bound: float):
        _ = wp.tid()
        t = wp.tile_zeros(shape=3, dtype=wp.vec3i, storage="shared")
        for k in range(vals.shape[0]):
            fused_tile.shared_add_fixed(t, slot[k], vals[k], True, scale, bound)
        fused_tile.block_sync()
        for k in range(3):
            out[k] = t[k]

    nan = float("nan")
    vals = np.array([[1e-6, -1e-6, 0.0], [2e-6, 0.0, 0.0], [1.0, -1.0, 0.05], [nan, 1e-3, nan]], np.float32)
    slot = np.array([0, 0, 1, 2], np.int32)
    out = wp.zeros(3, dtype=wp.vec3i, device="cpu")
    scale, bound = 2.0 ** 28, 0.1
    wp.launch_tiled(probe, dim=[1], inputs=[wp.array(vals, dtype=wp.vec3, device="cpu"),
                                            wp.array(slot, dtype=int, device="cpu"), out, scale, bound],
                    block_dim=1, device="cpu")
    got = out.numpy()
    step = np.float32(scale)
    assert got[0].tolist() == [round(1e-6 * step) + round(2e-6 * step), -round(1e-6 * step), 0]
    assert got[1].tolist() == [round(np.float32(bound) * step), -round(np.float32(bound) * step),
                               round(np.float32(0.05) * step)]
    assert got[2].tolist() == [0, round(np.float32(1e-3) * step), 0]


def test_a_frame_launch_ends_the_frame_and_counts_inverted_tets(setup):
    """fused.FOLD_END: a frame launch without contact also ends the frame (the last substep's
    velocities, x_safe, the fast vertices) and counts the inverted tets from shared memory, in place
    of integrate.advance's last launch and integrate.count_inverted. World 1's soft vertices are
    point-reflected through their centroid between two frames (every tet of theirs inverted, every
    vertex fast): the next frame's positions, velocities, x^i, x_safe and guard counters (the
    batch's and each world's) are the five-launch frame's bit for bit, and world 1 counts inverted
    tets (world 0, held open, none) and all its soft vertices fast."""
    asset, mount, open_, bent = setup
    runs = []
    for fz in (False, True):
        batch, _ = _run(asset, mount, open_, bent, Config(device="cpu", execution=Execution(fused_substep=fz, jacobi_gather=False)), frames=2)
        m = batch.solver.model
        x = batch.state.x.numpy()
        flip = (m.vertex_world.numpy() == 1) & (m.inv_mass.numpy() > 0.0)
        x[flip] = 2.0 * x[flip].mean(axis=0) - x[flip]
        batch.state.x.assign(x)
        batch.step(np.stack([open_[0], bent[0]]), np.stack([open_[1], bent[1]]))  # (world 0 held open)
        runs.append(batch)
    ref, fz = runs
    assert ref.solver._fused is None and fz.solver._fused is not None and fz.solver._fused.fold_end
    for name in ("x", "v", "x_prev", "x_safe", "guard"):
        assert np.array_equal(getattr(fz.state, name).numpy(), getattr(ref.state, name).numpy()), name
    g = fz.state.guard.numpy()
    assert g[1] > 0 and g[3] > 0, g[:4]  # (the reflection left tets inverted and vertices fast)
    assert g[4 + 4 * 1 + 1] == g[1] and g[4 + 4 * 0 + 1] == 0, g  # (world 1's inverted tets, in its own slot)
    assert g[4 + 4 * 1 + 3] == fz.solver._fused.n_soft > g[4 + 4 * 0 + 3], g  # (every soft vertex of world 1 fast)


@pytest.mark.parametrize("device", DEVICES)
def test_the_folded_frame_end_is_the_unfolded_one(setup, device, monkeypatch):
    """fused.FOLD_END and SKIP_BONES on and off, the rest of the fused kernel the same: after a frame
    in which world 1's soft vertices were point-reflected (tets inverted, vertices fast) the
    positions, velocities, x^i, x_safe and every guard counter are the same bits, on the CPU and on
    CUDA (whose fixed-point sum adds in no order that shows); the folded run records 2 fewer ops."""
    from physhand_mj.solver import fused

    asset, mount, open_, bent = setup
    runs = []
    for on in (False, True):
        monkeypatch.setattr(fused, "FOLD_END", on)
        monkeypatch.setattr(fused, "SKIP_BONES", on)
        batch, _ = _run(asset, mount, open_, bent, Config(device=device, execution=Execution(fused_substep=True)), frames=3)
        assert batch.solver._fused.fold_end == on and batch.solver._fused.skip_bones == on
        m = batch.solver.model
        x = batch.state.x.numpy()
        flip = (m.vertex_world.numpy() == 1) & (m.inv_mass.numpy() > 0.0)
        x[flip] = 2.0 * x[flip].mean(axis=0) - x[flip]
        batch.state.x.assign(x)
        runs.append((batch, batch.step(np.stack([open_[0], bent[0]]), np.stack([open_[1], bent[1]]))))
    (off, out_off), (on, out_on) = runs
    for name in ("x", "v", "x_prev", "x_safe", "guard"):
        assert np.array_equal(getattr(on.state, name).numpy(), getattr(off.state, name).numpy()), name
    g = on.state.guard.numpy()
    assert g[1] > 0 and g[3] > 0, g[:4]
    assert out_on["ops_run"] == out_off["ops_run"] - 2, (out_on["ops_run"], out_off["ops_run"])
