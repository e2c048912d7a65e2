"""Every example's test_final() runs (few frames / one picture each)."""

import importlib.util
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).parents[1] / "examples").glob("*.py"))
SLOW = {"hoi_grasps", "myosuite_episode"}  # 7-8 s each on a 2-core CPU: the slow set


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW else p for p in EXAMPLES],
                         ids=[p.stem for p in EXAMPLES])
def test_example(path, tmp_path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.test_final(tmp_path)
