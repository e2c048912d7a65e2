"""`physhand bench solver`: the JSON contract and its one-line errors."""

import json

import warp as wp

from physhand_mj.cli import main


def test_bench_solver_prints_the_contract_fields(capsys):
    assert main(["bench", "solver", "--steps", "2"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1, lines
    out = json.loads(lines[0])
    for key in ("ms_per_frame", "vertices", "tets", "substeps", "device"):
        assert key in out, key
    assert out["substeps"] == 10 and out["frame_dt_s"] == 0.005
    assert out["vertices"] == 10480 and out["ms_per_frame"] > 0
    assert out["nonfinite"] == 0 and out["inverted"] == 0
    # the CPU fuses a substep's start and constraint groups into one launch (Config.execution.fused_substep's
    # default), and with no contact stage a frame's substeps and its end into one (fused.FRAME_LAUNCH,
    # FOLD_END: the last substep's velocities and the inverted-tet count inside it): the frame's bone
    # poses, then that launch
    assert out["fused_substep"] is True and out["ops_run"] == 2, out


def test_bench_solver_errors_are_one_line(capsys):
    assert main(["bench", "solver", "--steps", "0"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--steps" in err
    if not wp.is_cuda_available():
        assert main(["bench", "solver", "--device", "cuda", "--steps", "1"]) == 1
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "CUDA" in err
