"""Batched rollouts (physhand_mj/batch_rollout.py, ``physhand rollout LIST --batch W``) against the serial
batch: the same rows, logs and skins, bit for bit (every world is solved at the origin), but for the
object-side depth of world 1, whose object points are tested against its skin moved 1 m out (float32
there: 0.01 um apart, measured)."""

from pathlib import Path
import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import physhand_mj as ph
from rollout_helpers import apple_b, read_csv
from physhand_mj.batch_rollout import rollout_batched
from physhand_mj.rollout import COUNTER_COLUMNS, LOG_COLUMNS, SUMMARY_COLUMNS, rollout_batch

APPLE, BOX = ph.scene_path("hoi_apple"), ph.scene_path("hoi_box")
STEPS = 3
TIMED = {"ms_per_frame", "ms_frame"}  # wall times (batched: the batch frame's / W)
# the object points' depth inside the skin: world 1's is measured on its skin moved 1 m out
OBJECT_DEPTH = ("initial_object_in_skin_max_um", "object_in_skin_max_um")
OBJECT_DEPTH_UM = 0.1
BATCH_FRAME = {"objects_near", "triangles_tested", "features_listed", "ops_run"}  # what the batch frame ran, all worlds



@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("batched")
    targets = [(APPLE, "grasp"), (tmp / "missing.xml", None), (BOX, "grasp"), (apple_b(tmp), None)]
    serial = rollout_batch(targets, tmp / "serial", steps=STEPS, device="cpu", progress=False)
    emitted = []
    batched = rollout_batched(targets, tmp / "batched", worlds=2, steps=STEPS, device="cpu", progress=False,
                              emit=emitted.append)
    return dict(tmp=tmp, serial=serial, batched=batched, emitted=emitted)


def _untimed(row, cols):
    return {c: row.get(c) for c in cols if c not in TIMED | {"log", "skin"}}


def test_rows_equal_the_serial_batch(runs):
    ser, bat = runs["serial"], runs["batched"]
    assert [(r["scene"], r["keyframe"]) for r in bat] == [(r["scene"], r["keyframe"]) for r in ser]
    cols = list(ser[0])
    # apple (world 0 of the apple batch), box (a batch of its own) and apple_b (world 1 of the apple
    # batch, its hand 1 mm further and lower: a 4.4 mm deep grasp pushed out): bit for bit
    for i in (0, 2, 3):
        b, s = _untimed(bat[i], cols), _untimed(ser[i], cols)
        for k in OBJECT_DEPTH:
            assert abs(b.pop(k) - s.pop(k)) <= OBJECT_DEPTH_UM, (k, bat[i], ser[i])
        assert b == s, (bat[i], ser[i])
    assert bat[1] == ser[1] and bat[1]["error"].startswith("scene file not found")
    assert ser[3]["penetration_count"] == 0 and ser[3]["initial_penetration_count"] > 1000
    assert sorted(r["scene"] for r in runs["emitted"]) == sorted(r["scene"] for r in bat)
    table = read_csv(runs["tmp"] / "batched" / "summary.csv")
    assert list(table[0]) == SUMMARY_COLUMNS and [t["scene"] for t in table] == [r["scene"] for r in ser]


def test_logs_and_skins_equal_the_serial_ones(runs):
    tmp = runs["tmp"]
    for run in ("hoi_apple-grasp", "hoi_box-grasp", "apple_b"):
        a, b = read_csv(tmp / "serial" / run / "log.csv"), read_csv(tmp / "batched" / run / "log.csv")
        assert list(b[0]) == LOG_COLUMNS and len(a) == len(b) == 1 + STEPS * 10
        skip = TIMED | BATCH_FRAME
        for ra, rb in zip(a, b):  # every column but the timings and what the batch frame ran
            da, db = ra["object_in_skin_max_um"], rb["object_in_skin_max_um"]  # ('' on rows that do not measure it)
            assert (da == db == "") or abs(float(da) - float(db)) <= OBJECT_DEPTH_UM, (da, db)
            assert {c: ra[c] for c in LOG_COLUMNS if c not in skip | {"object_in_skin_max_um"}} == \
                {c: rb[c] for c in LOG_COLUMNS if c not in skip | {"object_in_skin_max_um"}}
        # counters.csv: a row per frame; the feature lists' check per world (the box has feature points,
        # the apples none)
        counters = read_csv(tmp / "batched" / run / "counters.csv")
        assert list(counters[0]) == COUNTER_COLUMNS
        assert [r["step"] for r in counters] == [str(s + 1) for s in range(STEPS)]
        flags = {r["feature_slack_exceeded"] for r in counters}
        assert flags <= {"0", "1"} and flags if run == "hoi_box-grasp" else flags == {""}, (run, flags)
        sa = trimesh.load(tmp / "serial" / run / "skin_final.ply", process=False).vertices
        sb = trimesh.load(tmp / "batched" / run / "skin_final.ply", process=False).vertices
        np.testing.assert_array_equal(sa, sb, err_msg=run)


def test_cli_batch(tmp_path, capsys):
    lst = tmp_path / "runs.txt"
    lst.write_text(f"{APPLE} grasp\n{tmp_path / 'missing.xml'}\n")
    r = subprocess.run([sys.executable, "-m", "physhand_mj.cli", "rollout", str(lst), "--batch", "2", "--steps", "1",
                        "--device", "cpu", "--out", str(tmp_path / "b")], capture_output=True, text=True)
    assert r.returncode == 1, r.stderr[-800:]
    lines = [json.loads(x) for x in r.stdout.strip().splitlines()]
    assert len(lines) == 2 and {"penetration_count", "error"} <= set(lines[0]) | set(lines[1])
    assert (tmp_path / "b" / "hoi_apple-grasp" / "skin_final.ply").exists()
    from physhand_mj import cli

    for args, want in ((["--batch", "0"], "--batch must be at least 1"), (["--workers", "2"], "--workers needs --ray")):
        rc = cli.main(["rollout", str(lst), *args, "--out", str(tmp_path / "c")])  # (in this process: no new start)
        out, err = capsys.readouterr()
        line = [x for x in err.splitlines() if x.startswith("physhand rollout: error:")]
        assert rc == 1 and out == "" and len(line) == 1 and want in line[0], err[-800:]


def test_a_world_whose_object_pose_goes_nan_fails_alone(runs, monkeypatch):
    """One run's MuJoCo object pose turns NaN in its second frame: that run fails with the serial
    one-line error and keeps its log of frame 1, the other world of its batch finishes as in the
    unbroken batched run."""
    from physhand_mj import batch_rollout

    tmp = runs["tmp"]
    bad = apple_b(tmp)
    real = batch_rollout._Run.object_poses
    calls = {}

    def poses(self):
        pos, quat = real(self)
        if Path(self.scene).name == bad.name:
            calls[self.index] = calls.get(self.index, 0) + 1
            if calls[self.index] > 3:  # the batch's first poses (read twice) and frame 1's are fine, then NaN
                pos = np.full_like(pos, np.nan)
        return pos, quat

    monkeypatch.setattr(batch_rollout._Run, "object_poses", poses)
    rows = rollout_batched([(APPLE, "grasp"), (bad, None)], tmp / "nan", worlds=2, steps=STEPS, device="cpu",
                           progress=False)
    assert "non-finite MuJoCo pose for object geoms" in rows[1]["error"]
    assert not rows[0].get("error"), rows[0]
    assert _untimed(rows[0], SUMMARY_COLUMNS) == _untimed(runs["batched"][0], SUMMARY_COLUMNS)
    # the failed run's log keeps its start and frame 1 (its 10 substeps: written while frame 2 ran, the
    # batch being pipelined), as the unbroken run logged them
    log, ref = read_csv(tmp / "nan" / "apple_b" / "log.csv"), read_csv(tmp / "batched" / "apple_b" / "log.csv")
    assert len(log) == 1 + 10
    assert [{c: r[c] for c in LOG_COLUMNS if c not in TIMED | BATCH_FRAME} for r in log] == \
        [{c: r[c] for c in LOG_COLUMNS if c not in TIMED | BATCH_FRAME} for r in ref[:11]]


def test_a_finished_batch_is_freed_before_the_next(tmp_path):
    """Each batch's BatchedHands (its device arrays: ~7 GB at W = 4096) is gone once its batch ends:
    two W = 4096 batches in one process of benchmarks/batch_hoi.py ran out of an H100's memory until
    the first one's references were dropped and collected (docs/scale.md). On the CPU the batch is
    freed at return even without rollout_batched's collect; on CUDA (captured graphs) it was not
    isolated which reference held it."""
    import weakref

    seen = []
    rollout_batched([(APPLE, "grasp"), (apple_b(tmp_path), None)], tmp_path / "out", worlds=1, steps=1,
                    device="cpu", progress=False,
                    on_start=lambda hands, models, datas: seen.append(weakref.ref(hands)))
    assert len(seen) == 2 and seen[0]() is None and seen[1]() is None


def test_batches_are_grouped_as_the_list_is_walked(tmp_path):
    """iter_batch_groups yields a full batch before it loads the rest of the list (Ray submits it
    then): the third entry's scene does not exist until after the first batch came, and it loads."""
    from physhand_mj.batch_rollout import iter_batch_groups

    late = tmp_path / "late.xml"
    groups = iter_batch_groups([(APPLE, "grasp"), (apple_b(tmp_path), None), (late, None), (BOX, "nokey")], 2)
    assert next(groups) == [0, 1]
    late.write_text(apple_b(tmp_path).read_text())
    rest = list(groups)
    assert rest[0][0] == 3 and "nokey" in str(rest[0][1]), rest  # the box's unknown keyframe: a failed entry
    assert rest[1:] == [[2]], rest


def test_measure_every_in_a_batch(runs):
    """rollout_batched(measure_every=0): the object-side measure after the last frame only; every
    world's log equals the every-frame batch's but for the wall times and the earlier frames' object
    cells (empty), and the rows are the same."""
    tmp = runs["tmp"]
    targets = [(APPLE, "grasp"), (tmp / "missing.xml", None), (BOX, "grasp"), (tmp / "apple_b.xml", None)]
    last_only = rollout_batched(targets, tmp / "last_only", worlds=2, steps=STEPS, device="cpu", progress=False,
                                measure_every=0)
    cols = [c for c in SUMMARY_COLUMNS if c not in TIMED | {"log", "skin"}]
    assert [{c: r.get(c) for c in cols} for r in last_only] == [{c: r.get(c) for c in cols} for r in runs["batched"]]
    assert [r.get("object_in_skin_frame") for r in last_only] == [STEPS, None, STEPS, STEPS]
    obj = {"object_in_skin_count", "object_in_skin_max_um"}
    for run in ("hoi_apple-grasp", "hoi_box-grasp", "apple_b"):
        a = read_csv(tmp / "batched" / run / "log.csv")
        b = read_csv(tmp / "last_only" / run / "log.csv")
        assert len(a) == len(b) == 1 + STEPS * 10
        for ra, rb in zip(a, b):
            for col in LOG_COLUMNS:
                if col in TIMED:
                    continue
                if col in obj and rb["substep"] == "10" and int(rb["step"]) < STEPS:
                    assert rb[col] == "" and ra[col] != "", (run, rb["step"], col)
                else:
                    assert ra[col] == rb[col], (run, rb["step"], rb["substep"], col)


@pytest.mark.slow  # two batches of 2 worlds (the serial run's stop: tests/test_rollout.py, default set)
def test_a_stopped_batch_reports_the_frame_its_object_side_comes_from(tmp_path, monkeypatch):
    """A batch stopped by Ctrl-C during frame 3 (raised from the batch's submit of it) with measure_every=2:
    each world's summary has 2 steps and the object-side values of frame 2 (the vertex strategy:
    they change frame by frame), as the every-frame batch logged them; ``object_in_skin_frame`` 2."""
    from physhand_mj.batch import BatchedHands

    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None)]
    every = rollout_batched(targets, tmp_path / "every", worlds=2, steps=3, contact="vertex", device="cpu",
                            progress=False)
    calls = []
    submit = BatchedHands.submit

    def stop_in_frame_3(self, *a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return submit(self, *a, **k)

    monkeypatch.setattr(BatchedHands, "submit", stop_in_frame_3)
    stopped = rollout_batched(targets, tmp_path / "stopped", worlds=2, steps=3, contact="vertex", device="cpu",
                              progress=False, measure_every=2)
    for r, e, run in zip(stopped, every, ("hoi_apple-grasp", "apple_b")):
        assert r["interrupted"] and r["steps"] == 2 and r["object_in_skin_frame"] == 2, r
        row = next(x for x in read_csv(tmp_path / "every" / run / "log.csv") if x["step"] == "2" and x["substep"] == "10")
        assert (r["object_in_skin_count"], r["object_in_skin_max_um"]) == (
            int(row["object_in_skin_count"]), float(row["object_in_skin_max_um"])), (r, row)
    assert e["object_in_skin_frame"] == 3


@pytest.mark.slow  # three batches of 2 worlds
def test_a_batch_stopped_while_mujoco_steps_logs_the_frame_that_was_running(tmp_path, monkeypatch):
    """Ctrl-C while MuJoCo steps frame 3 (the batch pipelined: frame 2 still on the device then) stops
    where the serial loop stopped: frames 1 and 2 logged, each run's summary with 2 steps, its skin
    that of a 2-frame run; and Ctrl-C inside frame 2's log rows writes no row twice."""
    import mujoco

    from physhand_mj import batch_rollout

    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None)]
    two = rollout_batched(targets, tmp_path / "two", worlds=2, steps=2, device="cpu", progress=False)
    real_step = mujoco.mj_step
    calls = []

    def stop_in_frame_3(m, d, *a):
        calls.append(1)
        if len(calls) == 5:  # (2 worlds: frame 3's first call)
            raise KeyboardInterrupt
        return real_step(m, d, *a)

    monkeypatch.setattr(mujoco, "mj_step", stop_in_frame_3)
    stopped = rollout_batched(targets, tmp_path / "stopped", worlds=2, steps=4, device="cpu", progress=False)
    monkeypatch.setattr(mujoco, "mj_step", real_step)
    for r, t, run in zip(stopped, two, ("hoi_apple-grasp", "apple_b")):
        assert r["interrupted"] and r["steps"] == 2, r
        log = read_csv(tmp_path / "stopped" / run / "log.csv")
        assert sorted({int(x["step"]) for x in log}) == [0, 1, 2] and len(log) == 1 + 2 * 10
        a = trimesh.load(tmp_path / "stopped" / run / "skin_final.ply", process=False).vertices
        b = trimesh.load(tmp_path / "two" / run / "skin_final.ply", process=False).vertices
        np.testing.assert_array_equal(a, b, err_msg=run)
        assert r["penetration_count"] == t["penetration_count"], (r, t)

    real_rows = batch_rollout.frame_rows
    calls.clear()

    def stop_in_rows(*a, **k):
        calls.append(1)
        if len(calls) == 4:  # (world 1's rows of frame 2)
            raise KeyboardInterrupt
        return real_rows(*a, **k)

    monkeypatch.setattr(batch_rollout, "frame_rows", stop_in_rows)
    rollout_batched(targets, tmp_path / "rows", worlds=2, steps=4, device="cpu", progress=False)
    for run, frames in (("hoi_apple-grasp", [0, 1, 2]), ("apple_b", [0, 1])):
        log = read_csv(tmp_path / "rows" / run / "log.csv")
        keys = [(x["step"], x["substep"]) for x in log]
        assert len(keys) == len(set(keys)), run  # no row twice
        assert sorted({int(x["step"]) for x in log}) == frames, run
