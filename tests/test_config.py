"""Config: the user's options, the expert groups, and the validated Settings."""

import dataclasses
import enum
import re
from pathlib import Path

import pytest

import physhand_mj as ph

DOC = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def _user_fields():
    return [f.name for f in dataclasses.fields(ph.Config) if f.name not in ("tuning", "execution")]


def test_validate_returns_a_checked_copy_and_leaves_the_config_alone():
    c = ph.Config(frame_dt=0.02, substeps=4, contact="opt")
    s = c.validate()
    assert isinstance(s, ph.Settings) and s is not c
    assert (s.substeps, s.substeps_requested, s.contact) == (10, 4, ph.Strategy.OPT)
    assert (c.substeps, c.contact) == (4, "opt")  # the Config as the user wrote it
    assert s.validate() is s and c.validate() == s


def test_settings_are_flat_frozen_and_checked_when_replaced():
    s = ph.Config(tuning=ph.Tuning(feature_offset=5e-5), execution=ph.Execution(cuda_graph=False)).validate()
    assert (s.feature_offset, s.cuda_graph, s.contact_passes) == (5e-5, False, 8)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.substeps = 3
    with pytest.raises(ValueError, match="Config.tuning.feature_offset must be a finite number >= 0"):
        dataclasses.replace(s, feature_offset=-1.0)
    with pytest.raises(ValueError, match="Config.tuning must be a physhand_mj.Tuning"):
        ph.Config(tuning={"feature_offset": 1e-5}).validate()


def test_the_groups_do_not_share_a_name():
    names = [*_user_fields(), *(f.name for f in dataclasses.fields(ph.Tuning)),
             *(f.name for f in dataclasses.fields(ph.Execution))]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)
    assert {f.name for f in dataclasses.fields(ph.Settings)} == set(names) | {"substeps_requested"}


def test_the_docs_table_lists_every_user_option_with_its_default():
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \|", DOC.read_text(), flags=re.M)
    documented = {name: default.strip() for name, default in rows}
    assert list(documented) == _user_fields(), "docs/config.md's table and Config's fields differ"
    for f in dataclasses.fields(ph.Config):
        if f.name not in documented:
            continue
        doc, default = documented[f.name], f.default
        if isinstance(default, enum.Enum) or isinstance(default, bool) or default is None:
            assert doc == (default.name if isinstance(default, enum.Enum) else str(default)), f.name
        elif isinstance(default, (int, float)):
            assert float(doc) == pytest.approx(default), f.name


def test_a_preset_is_a_config():
    c = ph.Config.preset("interactive", device="cpu")
    assert isinstance(c, ph.Config) and c.substeps == 5
    with pytest.raises(ValueError, match="unknown Config preset"):
        ph.Config.preset("fast")
