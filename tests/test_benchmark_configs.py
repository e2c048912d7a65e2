"""The benchmarks' Config plumbing: a variant given as flat options becomes the Config it names
(benchmarks/hard_contact_hold.py failed on every run once contact_offset moved to Tuning)."""

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "hard_contact_hold.py"


@pytest.fixture(scope="module")
def hold():
    spec = importlib.util.spec_from_file_location("hard_contact_hold", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_hold_variant_config(hold):
    """A variant of Config, Tuning and Execution options, flat, on path 2 at perturb 1e-4: each option
    set, the contact offset (given or the default) scaled by 1 + 2e-4."""
    import physhand_mj as ph

    cfg = hold.path_config("cpu", {"skin_compression": False, "contact_offset": 5.0e-6, "feature_last": False}, 2, 1.0e-4)
    assert cfg.skin_compression is False and cfg.tuning.feature_last is False
    assert cfg.tuning.contact_offset == pytest.approx(5.0e-6 * (1.0 + 2.0e-4), rel=1e-12)
    base = hold.path_config("cpu", {}, 0, 1.0e-4)
    assert base.tuning.contact_offset == ph.Tuning().contact_offset
    cfg.validate()
