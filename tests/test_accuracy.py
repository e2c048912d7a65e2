"""`physhand bench accuracy`: the Pareto front, the per-setting summary and a --quick run's files."""

import csv
import json

import numpy as np
import pytest
import warp as wp

from physhand_mj.bench.accuracy import (POINT_COLUMNS, ROW_COLUMNS, SweepPoint, cheapest_zero, default_point,
                                        pareto_front, summarize_points, sweep_points)
from physhand_mj.cli import main


def test_pareto_front_excludes_dominated_points():
    costs = np.array([
        [10.0, 5.0],   # front: fastest
        [20.0, 1.0],   # front
        [30.0, 0.0],   # front: most accurate
        [25.0, 1.0],   # dominated by row 1 (slower, as deep)
        [40.0, 3.0],   # dominated by rows 1 and 2
        [20.0, 1.0],   # equal to row 1: kept with it
        [np.nan, 0.0],  # unmeasured: never on the front
    ])
    assert pareto_front(costs).tolist() == [True, True, True, False, False, True, False]
    # three objectives: a point better in one measure only stays on the front
    c3 = np.array([[10.0, 0.0, 9.0], [10.0, 9.0, 0.0], [12.0, 0.0, 9.0]])
    assert pareto_front(c3).tolist() == [True, True, False]
    with pytest.raises(ValueError, match="2-D"):
        pareto_front([1.0, 2.0])


def test_summary_takes_the_worst_workload_and_flags_the_front():
    pts = [SweepPoint("vertex", features=False, side_aware=False), default_point(),
           SweepPoint(passes=2)]  # pts[1]: Config()'s

    def row(pt, w, ms, skin, obj):
        return dict(point=pt.name, workload=w, ms_per_frame=ms, hold_skin_max_um=skin, hold_object_max_um=obj,
                    skin5_count=int(skin > 0), skin9_count=0, object_count=int(obj > 0), finite=True)

    rows = [row(pts[0], "a", 10, 500, 900), row(pts[0], "b", 20, 0, 0),        # fast, deep
            row(pts[1], "a", 40, 0, 0), row(pts[1], "b", 60, 2, 0),            # slow, shallow
            row(pts[2], "a", 45, 0, 0), row(pts[2], "b", 65, 3, 1)]            # slower and deeper than pts[1]
    table = summarize_points(pts, rows)
    assert [set(POINT_COLUMNS) <= set(t) for t in table] == [True] * 3
    assert [t["ms_per_frame"] for t in table] == [15, 50, 55]
    assert [(t["skin_um"], t["object_um"]) for t in table] == [(500, 900), (2, 0), (3, 1)]
    assert [t["pareto_both"] for t in table] == [True, True, False]
    assert [t["default"] for t in table] == [False, True, False]
    assert not any(t["zero"] for t in table) and cheapest_zero(table) is None
    rows[3]["hold_skin_max_um"] = 0  # pts[1] now at zero everywhere: the cheapest at zero, at its substeps only
    table = summarize_points(pts, rows)
    assert [t["zero"] for t in table] == [False, True, False]
    assert cheapest_zero(table)["point"] == pts[1].name == cheapest_zero(table, substeps=10)["point"]
    assert cheapest_zero(table, substeps=5) is None


def test_sweep_names_are_unique_and_hold_the_default():
    pts = sweep_points()
    assert len({p.name for p in pts}) == len(pts)
    assert sum(p.is_default() for p in pts) == 1
    assert {p.contact for p in pts} == {"vertex", "opt", "multires"}
    assert {p.passes for p in pts} >= {2, 4, 8} and {p.substeps for p in pts} >= {5, 10}


def test_bench_accuracy_quick_writes_csv_json_png(tmp_path, capsys):
    assert main(["bench", "accuracy", "--quick", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1, lines
    out = json.loads(lines[0])
    assert out["command"] == "bench accuracy" and out["points"] == 2 and out["frames"] == 2
    assert len(out["workloads"]) == 3
    assert out["device"] == "cpu" and "cpu" in out["device_name"]
    with open(tmp_path / "accuracy_cpu.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == ROW_COLUMNS
        rows = list(reader)
    assert len(rows) == 2 * len(out["workloads"])
    assert all(float(r["ms_per_frame"]) > 0 and r["finite"] == "True" for r in rows)
    data = json.loads((tmp_path / "accuracy_cpu.json").read_text())
    assert len(data["points"]) == 2 and list(data["points"][0]) == POINT_COLUMNS
    assert data["device_name"] == out["device_name"] and len(data["rows"]) == len(rows)
    assert list(data["heldout"]) == [w for w in out["workloads"] if w.startswith("heldout:")]
    assert all(h["feasible"] and h["clearance_mm"] > 0.5 for h in data["heldout"].values())
    assert out["default_on_front"] is not None and out["pareto"]  # the front is never empty
    assert set(out["cheapest_zero"]) == {"any", "default_substeps"}
    assert (tmp_path / "accuracy_cpu.png").stat().st_size > 10_000


def test_the_cone_experiment_is_a_sweep_workload():
    """cone:paper runs the paper's sheet on a cone under a setting: vertex (6 queries) leaves the cone
    tip through the sheet, multires ends the paper's order-5 metric at zero; an open sheet has no
    inside, so no object point is counted."""
    from physhand_mj.bench.accuracy import SweepPoint, check_workloads, run_sweep

    rows = run_sweep([SweepPoint("vertex", features=False, side_aware=False), SweepPoint()], ["cone:paper"],
                     device="cpu", frames=20)
    vertex, multires = rows
    assert vertex["finite"] and multires["finite"]
    assert vertex["skin5_count"] > 0 and vertex["skin5_max_um"] > 100.0, vertex  # measured 16 / 1,859 um
    assert multires["skin5_count"] == 0, multires
    assert vertex["object_count"] == multires["object_count"] == 0
    with pytest.raises(ValueError, match="cone:paper"):
        check_workloads(["cone:other"])


def test_heldout_workloads_are_the_generators_cases():
    """heldout:SEED:I is case I of bench/heldout.py's generator; the default sweep holds four
    feasible ones of different kinds; a malformed one is refused by name."""
    import physhand_mj as ph
    from physhand_mj.bench.accuracy import QUICK_WORKLOADS, WORKLOADS, check_workloads, heldout_case
    from physhand_mj.bench.heldout import draw_case

    asset = ph.load_asset()
    held = [w for w in WORKLOADS if w.startswith("heldout:")]
    assert len(held) >= 4 and any(w.startswith("heldout:") for w in QUICK_WORKLOADS)
    check_workloads(held)
    cases = [heldout_case(w[len("heldout:"):], asset) for w in held]
    assert len({h.kind for h in cases}) == len(cases) and all(h.feasible for h in cases), [h.label for h in cases]
    assert cases[0].label == draw_case(*(int(v) for v in held[0].split(":")[1:]), asset).label
    for bad in ("heldout:0", "heldout:a:1", "heldout:0:-1", "heldout:0:1:2"):
        with pytest.raises(ValueError, match="heldout:SEED:I"):
            check_workloads([bad])


def test_bench_accuracy_errors_are_one_line(capsys, tmp_path):
    assert main(["bench", "accuracy", "--quick", "--frames", "1", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--frames" in err
    assert main(["bench", "accuracy", "--quick", "--workloads", "hoi:box,case:knife@elbow", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "knife@elbow" in err
    if not wp.is_cuda_available():
        assert main(["bench", "accuracy", "--quick", "--device", "cuda", "--out", str(tmp_path)]) == 1
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "CUDA" in err


def test_config_presets_are_the_recommended_sweep_points():
    """Config.preset names the settings of docs/accuracy.md's recommendation table: each equals a
    point the sweep measured (so its figures there are the preset's), and a bad name says the choices."""
    import dataclasses

    from physhand_mj.bench.accuracy import sweep_points
    from physhand_mj.types import Config

    by_name = {p.name: p for p in sweep_points()}
    want = {"default": "multires 21x2+feat+side p8 s10", "interactive": "multires 21x2+feat+side p8 s5",
            "dataset": "opt+feat+side p8 s10", "robot_pads": "opt+feat+side p8 s5"}
    for preset, point in want.items():
        a = dataclasses.asdict(Config.preset(preset, device="cpu").validate())
        b = dataclasses.asdict(by_name[point].config("cpu").validate())
        assert a == b, (preset, {k: (a[k], b[k]) for k in a if a[k] != b[k]})
    assert Config.preset("interactive", substeps=7).substeps == 7  # overrides win
    with pytest.raises(ValueError, match="unknown Config preset 'fast'.*interactive"):
        Config.preset("fast")


def test_substeps_longer_than_the_stable_limit_are_raised_or_warned():
    """20 ms frames with 4 substeps (5 ms) collapse the flesh (tests/stress): by default validate()
    runs enough substeps (Config.max_substep, 2 ms: 10), keeps the count asked for and stays so when
    validated again; with max_substep=None it keeps the count and warns with the count that holds;
    2 ms substeps are left alone; a bad max_substep says what to give."""
    import warnings

    from physhand_mj.types import Config

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        c = Config(frame_dt=0.02, substeps=4).validate()
        assert (c.substeps, c.substeps_requested, c.substep_dt) == (10, 4, pytest.approx(0.002))
        c.validate()
        assert (c.substeps, c.substeps_requested) == (10, 4)
        assert Config(frame_dt=0.02, substeps=3, max_substep=0.0015).validate().substeps == 14
        c = Config(frame_dt=0.02, substeps=10).validate()
        assert (c.substeps, c.substeps_requested) == (10, None)
        c = Config().validate()
        assert (c.substeps, c.substeps_requested) == (10, None)
    with pytest.warns(RuntimeWarning, match=r"substeps of 5 ms .* use substeps >= 10"):
        c = Config(frame_dt=0.02, substeps=4, max_substep=None).validate()
    assert (c.substeps, c.substeps_requested) == (4, None)
    for bad in (0.0, -0.002, float("nan"), float("inf"), "2ms", True):
        with pytest.raises(ValueError, match="Config.max_substep must be None or a finite number of seconds > 0"):
            Config(max_substep=bad).validate()
