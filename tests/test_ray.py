"""Rollouts on Ray (physhand_mj/distributed.py) against the serial batch: same rows, same files, a
failed entry, retries after a killed worker or an exception, Ctrl-C on the driver. A local Ray of
2 CPU workers; CPU rollouts are deterministic, so the two agree exactly but for timings."""

import _thread
import logging
import os
import signal
import threading
import time

import pytest

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.slow  # a local Ray's start and its workers' runs: the README's slow set

import physhand_mj as ph  # noqa: E402
from physhand_mj.distributed import rollout_ray  # noqa: E402
from physhand_mj.rollout import SUMMARY_COLUMNS, rollout_batch  # noqa: E402
from rollout_helpers import apple_b, read_csv  # noqa: E402

APPLE, BOX, GLASS = (ph.scene_path(s) for s in ("hoi_apple", "hoi_box", "hoi_glass1"))
STEPS = 2
TIMED = {"ms_per_frame", "ms_frame"}  # wall times: the only columns allowed to differ


@pytest.fixture(scope="module")
def local_ray():
    # Ray's workers inherit SIGINT's disposition from this process; run as a background job (SIGINT
    # ignored, as a shell starts one) they would ignore the cancel's KeyboardInterrupt and run on
    # (measured: the Ctrl-C tests failed in background pytest runs, passed in the foreground)
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    finally:
        signal.signal(signal.SIGINT, old)
    yield
    ray.shutdown()



def _untimed(rows, cols=SUMMARY_COLUMNS):
    return [{c: r.get(c) for c in cols if c not in TIMED} for r in rows]


@pytest.fixture(scope="module")
def both(local_ray, tmp_path_factory):
    """The same 3-entry list (the last one missing) run serially and on Ray."""
    tmp = tmp_path_factory.mktemp("ray")
    targets = [(APPLE, "grasp"), (tmp / "missing.xml", None), (BOX, "grasp")]
    serial = rollout_batch(targets, tmp / "serial", steps=STEPS, device="cpu", progress=False)
    emitted = []
    t = time.perf_counter()
    rows = rollout_ray(targets, tmp / "ray", steps=STEPS, device="cpu", progress=False, emit=emitted.append)
    return dict(tmp=tmp, serial=serial, ray=rows, emitted=emitted, ray_s=time.perf_counter() - t)


def test_ray_rows_match_the_serial_batch(both):
    serial, rows = both["serial"], both["ray"]
    assert _untimed(rows) == _untimed(serial), (rows, serial)
    assert [r["scene"] for r in rows] == [str(APPLE), str(both["tmp"] / "missing.xml"), str(BOX)]
    assert rows[0]["initial_penetration_count"] > 1000 and rows[0]["penetration_count"] == 0, rows[0]
    assert sorted(r["scene"] for r in both["emitted"]) == sorted(r["scene"] for r in rows)


def test_failed_entry_is_a_row_with_its_error_and_the_others_finish(both):
    bad = both["ray"][1]
    assert bad["error"].startswith("scene file not found") and bad["finite"] is False, bad
    assert all("error" not in r and r["finite"] and r["steps"] == STEPS for r in both["ray"][::2])


def test_run_folders_hold_the_same_files(both):
    ser, par = both["tmp"] / "serial", both["tmp"] / "ray"
    assert sorted(p.name for p in par.iterdir()) == sorted(p.name for p in ser.iterdir())
    for run in ("hoi_apple-grasp", "hoi_box-grasp"):
        assert sorted(p.name for p in (par / run).iterdir()) == ["counters.csv", "log.csv", "skin_final.ply"]
        a, b = read_csv(ser / run / "log.csv"), read_csv(par / run / "log.csv")
        assert len(a) == 1 + STEPS * 10 and _untimed(a, a[0]) == _untimed(b, a[0])
        assert (ser / run / "skin_final.ply").read_bytes() == (par / run / "skin_final.ply").read_bytes()
    assert _untimed(read_csv(par / "summary.csv")) == _untimed(read_csv(ser / "summary.csv"))
    assert both["ray"][0]["log"] == str(par / "hoi_apple-grasp" / "log.csv")


def test_a_worker_on_another_node_ships_its_files(local_ray, tmp_path):
    """Under Ray Client or on another node the run goes to a temporary folder there and its files
    come back to the driver's run folder (here: a driver node id no worker has)."""
    from physhand_mj.distributed import _collect, _run_one

    ref = ray.remote(_run_one).options(num_cpus=1).remote(str(APPLE), "grasp", str(tmp_path / "unused"),
                                                          "another-node", os.getcwd(), dict(steps=1, device="cpu"))
    row = _collect(ray, ref, (APPLE, "grasp"), tmp_path / "run", tmp_path / "run", 0)
    assert not (tmp_path / "unused").exists() and row["steps"] == 1 and row["scene"] == str(APPLE), row
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["counters.csv", "log.csv", "skin_final.ply"]
    assert len(read_csv(row["log"])) == 1 + 10 and row["skin"] == str(tmp_path / "run" / "skin_final.ply")


# rollout(on_start=...) runs in the worker; functions made here (not module attributes) travel by
# value, as the worker cannot import this test module
def _crash_once(marker):
    def on_start(hand, model, data):
        if not os.path.exists(marker):
            open(marker, "w").close()
            os._exit(1)  # the worker dies: Ray reruns the task
    return on_start


def _always_raise():
    def on_start(hand, model, data):
        raise RuntimeError("flaky device")
    return on_start


def test_killed_worker_is_retried_then_an_exception_fails_after_its_retries(local_ray, tmp_path):
    rows = rollout_ray([(APPLE, "grasp")], tmp_path / "a", steps=1, device="cpu", progress=False, max_retries=1,
                       on_start=_crash_once(str(tmp_path / "crashed")))
    assert (tmp_path / "crashed").exists() and rows[0]["steps"] == 1 and "error" not in rows[0], rows
    rows = rollout_ray([(APPLE, "grasp")], tmp_path / "b", steps=1, device="cpu", progress=False, max_retries=0,
                       on_start=_always_raise())
    assert rows[0]["error"] == "RuntimeError: flaky device (failed 1 times)", rows
    assert read_csv(tmp_path / "b" / "summary.csv")[0]["error"] == rows[0]["error"]


def test_ctrl_c_cancels_keeps_partial_logs_and_writes_the_summary(local_ray, tmp_path):
    """Two long runs on the two workers, a third waiting: SIGINT on the driver once both logged 3 frames.
    The hand never sleeps here (sleep_speed=0): asleep, the box's 400 frames ran in seconds, before the
    apple had logged its 3 frames, and that run was not interrupted."""
    out = tmp_path / "c"
    logs = [out / "hoi_apple-grasp" / "log.csv", out / "hoi_box-grasp" / "log.csv"]
    done = threading.Event()

    def interrupt():
        deadline = time.time() + 300  # (slow under load: the runs must have logged 3 frames first)
        while time.time() < deadline and not all(p.exists() and len(p.read_text().splitlines()) > 31 for p in logs):
            if done.wait(0.2):
                return
        if not done.is_set():
            _thread.interrupt_main()

    old = signal.signal(signal.SIGINT, signal.default_int_handler)  # a background job may ignore SIGINT
    try:
        threading.Thread(target=interrupt, daemon=True).start()
        rows = rollout_ray([(APPLE, "grasp"), (BOX, "grasp"), (GLASS, "grasp")], out, steps=400, device="cpu",
                           num_workers=2, progress=False, config={"sleep_speed": 0.0})
    finally:
        done.set()
        signal.signal(signal.SIGINT, old)
    assert [r["interrupted"] for r in rows] == [True] * 3, rows
    for r, log in zip(rows[:2], logs):
        assert 3 <= r.get("steps", -1) < 400 and "error" not in r, r
        assert len(read_csv(log)) == 1 + r["steps"] * 10
        assert log.with_name("skin_final.ply").exists()
    assert rows[2]["error"] == "cancelled (Ctrl-C)" and not (out / "hoi_glass1-grasp").exists()
    table = read_csv(out / "summary.csv")
    assert [t["interrupted"] for t in table] == ["True"] * 3 and int(table[0]["steps"]) == rows[0]["steps"]


def test_batch_on_ray_matches_rollout_batched(local_ray, tmp_path):
    """--ray --batch 2: the two runs (the same objects) are one batch in one Ray task; rows, logs, skins
    and the summary as rollout_batched's on the same list (the same batch, so exactly, but timings
    and what the batch frame ran)."""
    from physhand_mj.batch_rollout import batch_groups, rollout_batched

    batch_frame = {"objects_near", "triangles_tested", "features_listed", "ops_run"}  # tests/test_batch_rollout.py
    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None)]
    assert batch_groups(targets, 2) == ([[0, 1]], {})
    local = rollout_batched(targets, tmp_path / "local", worlds=2, steps=STEPS, device="cpu", progress=False)
    emitted = []
    rows = rollout_ray(targets, tmp_path / "ray", batch=2, steps=STEPS, device="cpu", progress=False,
                       emit=emitted.append)
    cols = [c for c in SUMMARY_COLUMNS if c not in batch_frame | {"log", "skin"}]
    assert _untimed(rows, cols) == _untimed(local, cols), (rows, local)
    assert [r["scene"] for r in rows] == [str(APPLE), str(tmp_path / "apple_b.xml")] and len(emitted) == 2
    assert all("error" not in r and r["finite"] and r["steps"] == STEPS for r in rows), rows
    assert rows[1]["log"] == str(tmp_path / "ray" / "apple_b" / "log.csv")
    for run in ("hoi_apple-grasp", "apple_b"):
        a, b = read_csv(tmp_path / "local" / run / "log.csv"), read_csv(tmp_path / "ray" / run / "log.csv")
        keep = [c for c in a[0] if c not in batch_frame]
        assert len(a) == 1 + STEPS * 10 and _untimed(a, keep) == _untimed(b, keep)
        assert ((tmp_path / "local" / run / "skin_final.ply").read_bytes()
                == (tmp_path / "ray" / run / "skin_final.ply").read_bytes())
    ray_table, local_table = read_csv(tmp_path / "ray" / "summary.csv"), read_csv(tmp_path / "local" / "summary.csv")
    assert _untimed(ray_table, cols) == _untimed(local_table, cols)


def test_killed_batch_worker_is_retried_as_a_whole(local_ray, tmp_path):
    """--ray --batch 2: the worker running the batch dies once (after the batch settled); Ray reruns the
    task and both runs of the batch finish, their files in place."""
    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None)]
    rows = rollout_ray(targets, tmp_path / "a", batch=2, steps=1, device="cpu", progress=False, max_retries=1,
                       on_start=_crash_once(str(tmp_path / "crashed")))
    assert (tmp_path / "crashed").exists(), "the first attempt ran"
    assert [r["steps"] for r in rows] == [1, 1] and all("error" not in r for r in rows), rows
    for run in ("hoi_apple-grasp", "apple_b"):
        assert len(read_csv(tmp_path / "a" / run / "log.csv")) == 1 + 10
        assert (tmp_path / "a" / run / "skin_final.ply").exists()
    assert len(read_csv(tmp_path / "a" / "summary.csv")) == 2


def test_ctrl_c_cancels_batches_keeps_partial_logs_and_writes_the_summary(local_ray, tmp_path):
    """--ray --batch 2: three batches (the two apple runs, the box, the glass) on two workers; SIGINT on
    the driver once the first two batches logged 3 frames: their runs end interrupted with their logs,
    the waiting batch's run is cancelled, the summary holds all."""
    import glob
    import tempfile

    out = tmp_path / "c"
    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None), (BOX, "grasp"), (GLASS, "grasp")]
    # a batch task writes into a temporary folder on its node and moves the runs into place at its end
    pattern = os.path.join(tempfile.gettempdir(), "physhand_batch_*", "{}", "log.csv")
    done = threading.Event()
    # (batch folders an earlier, interrupted run left behind are not this run's: they would fire the
    # interrupt at once)
    stale = set(glob.glob(os.path.join(tempfile.gettempdir(), "physhand_batch_*")))

    def logged(run):
        return any(len(open(p).read().splitlines()) > 31 for p in glob.glob(pattern.format(run))
                   if os.path.dirname(os.path.dirname(p)) not in stale)

    def interrupt():
        deadline = time.time() + 300  # (slow under load)
        while time.time() < deadline and not (logged("hoi_apple-grasp") and logged("hoi_box-grasp")):
            if done.wait(0.2):
                return
        if not done.is_set():
            _thread.interrupt_main()

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Thread(target=interrupt, daemon=True).start()
        rows = rollout_ray(targets, out, batch=2, steps=400, device="cpu", num_workers=2, progress=False)
    finally:
        done.set()
        signal.signal(signal.SIGINT, old)
    by_scene = {r["scene"]: r for r in rows}
    assert len(rows) == 4 and all(r["interrupted"] for r in rows), rows
    for scene in (str(APPLE), str(tmp_path / "apple_b.xml"), str(BOX)):
        r = by_scene[scene]
        assert 3 <= r.get("steps", -1) < 400 and "error" not in r, r
        assert len(read_csv(r["log"])) == 1 + r["steps"] * 10
    assert by_scene[str(GLASS)]["error"] == "cancelled (Ctrl-C)" and not (out / "hoi_glass1-grasp").exists()
    assert len(read_csv(out / "summary.csv")) == 4


def test_a_batch_task_on_another_node_ships_its_files(local_ray, tmp_path):
    from physhand_mj.distributed import _collect_group, _run_group

    ref = ray.remote(_run_group).options(num_cpus=1).remote([(str(APPLE), "grasp")], [str(tmp_path / "unused")],
                                                            "another-node", os.getcwd(), 2, dict(steps=1, device="cpu"))
    rows = _collect_group(ray, ref, [(APPLE, "grasp")], [tmp_path / "run"], [tmp_path / "run"], 0)
    assert not (tmp_path / "unused").exists() and rows[0]["steps"] == 1 and rows[0]["scene"] == str(APPLE), rows
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["counters.csv", "log.csv", "skin_final.ply"]
    assert rows[0]["log"] == str(tmp_path / "run" / "log.csv") and len(read_csv(rows[0]["log"])) == 1 + 10


def test_batches_with_a_missing_scene_on_ray_and_the_tasks_times(local_ray, tmp_path):
    """--ray --batch 2 on [apple, missing, apple_b]: the driver fails the missing scene's run as it
    walks the list (row and emit) and the two apple runs still make one batch; each batch row says
    when its task started, had set up, and ended (benchmarks/ray_scaling.py splits the start with them)."""
    targets = [(APPLE, "grasp"), (tmp_path / "missing.xml", None), (apple_b(tmp_path), None)]
    emitted = []
    t0 = time.time()
    rows = rollout_ray(targets, tmp_path / "ray", batch=2, steps=1, device="cpu", progress=False,
                       emit=emitted.append)
    assert "error" in rows[1] and "missing.xml" in rows[1]["error"] and not rows[1]["finite"], rows[1]
    assert all("error" not in rows[i] and rows[i]["steps"] == 1 for i in (0, 2)), rows
    assert len(emitted) == 3 and emitted[0] is rows[1]  # the failed run first: it needs no task
    a, b = rows[0], rows[2]
    assert (a["task_pid"], a["task_start"], a["task_end"]) == (b["task_pid"], b["task_start"], b["task_end"])
    assert t0 < a["task_start"] < a["task_ready"] < a["task_end"] < time.time(), a
    assert len(read_csv(tmp_path / "ray" / "summary.csv")) == 3


def test_batches_go_out_while_the_list_is_grouped(local_ray, tmp_path):
    """--ray --batch 2 --workers 1: the driver groups one batch ahead of the running one, not the
    whole list first. The fifth run's scene is written by the first batch's on_start (in its
    worker), so it loads only if the driver reaches it after that batch ran."""
    late = tmp_path / "late.xml"
    text = apple_b(tmp_path).read_text()

    def write_late(*_):
        late.write_text(text)

    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None)] * 2 + [(late, None)]
    rows = rollout_ray(targets, tmp_path / "ray", batch=2, num_workers=1, steps=1, device="cpu", progress=False,
                       on_start=write_late)
    assert [r.get("error") for r in rows] == [None] * 5, rows
    assert rows[4]["scene"] == str(late) and rows[4]["steps"] == 1


def test_an_error_while_grouping_writes_the_table_and_raises(local_ray, tmp_path, monkeypatch):
    """An unexpected exception while the driver groups the list (after a batch went out) is raised
    to the caller, with the summary of what had finished written and the running batch cancelled."""
    import physhand_mj.batch_rollout as br

    def groups(targets, worlds, asset=None):
        yield [0, 1]
        raise KeyError("a broken scene list")

    monkeypatch.setattr(br, "iter_batch_groups", groups)
    targets = [(APPLE, "grasp"), (apple_b(tmp_path), None), (BOX, "grasp")]
    with pytest.raises(KeyError, match="broken scene list"):
        rollout_ray(targets, tmp_path / "ray", batch=2, steps=1, device="cpu", progress=False)
    assert (tmp_path / "ray" / "summary.csv").exists()
    assert ray.is_initialized()  # the caller's Ray is left as it was
