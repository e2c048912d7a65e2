"""Every example's test_final() runs (few frames / one picture each)."""

import importlib.util
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).parents[1] / "examples").glob("*.py"))
SLOW = {"hoi_grasps", "myosuite_episode", "train_ppo"}  # 7-14 s each on a 2-core CPU: the slow set


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW else p for p in EXAMPLES],
                         ids=[p.stem for p in EXAMPLES])
def test_example(path, tmp_path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.test_final(tmp_path)


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_dmc_example_exits_without_tracebacks(tmp_path):
    """Run as a script, the dm_control example frees its render context before exit: dm_control's own
    exit hook, run after Python shut down the thread the context lives on, prints tracebacks."""
    import subprocess
    import sys

    path = Path(__file__).parents[1] / "examples" / "dmc_random_policy.py"
    r = subprocess.run([sys.executable, str(path), str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr[-2000:]
    assert (tmp_path / "dmc_hand_hold_apple.png").exists()
