"""A corrupted, incomplete or wrong-version asset fails with a message that says what to do."""

import json

import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.asset import save_asset, validate_asset


def _copy(asset, tmp_path, **changes):
    import dataclasses

    path = tmp_path / "a.npz"
    save_asset(dataclasses.replace(asset, **changes), path)
    return path


def test_roundtrip(asset, tmp_path):
    back = ph.load_asset(_copy(asset, tmp_path))
    np.testing.assert_array_equal(back.tets, asset.tets)
    assert back.meta == json.loads(json.dumps(asset.meta))


def test_missing_file(tmp_path):
    with pytest.raises(ph.AssetError, match="not found.*build-hand"):
        ph.load_asset(tmp_path / "nope.npz")


def test_not_an_npz(tmp_path):
    p = tmp_path / "bad.npz"
    p.write_bytes(b"this is not a zip file")
    with pytest.raises(ph.AssetError, match="not a readable .npz"):
        ph.load_asset(p)


def test_truncated_file(asset, tmp_path):
    p = _copy(asset, tmp_path)
    p.write_bytes(p.read_bytes()[: 5000])
    with pytest.raises(ph.AssetError):
        ph.load_asset(p)


def test_wrong_schema_version(asset, tmp_path):
    p = _copy(asset, tmp_path)
    with np.load(p) as z:
        data = dict(z)
    data["schema_version"] = np.int64(99)
    np.savez(p, **data)
    with pytest.raises(ph.AssetError, match="schema version 99.*reads version 1.*build-hand"):
        ph.load_asset(p)


def test_missing_array(asset, tmp_path):
    p = _copy(asset, tmp_path)
    with np.load(p) as z:
        data = {k: z[k] for k in z.files if k != "tets"}
    np.savez(p, **data)
    with pytest.raises(ph.AssetError, match="lacks arrays.*tets"):
        ph.load_asset(p)


@pytest.mark.parametrize("field,mutate,message", [
    ("positions", lambda a: np.where(np.arange(len(a))[:, None] == 3, np.nan, a), "non-finite"),
    ("tets", lambda a: a[:, [1, 0, 2, 3]], "non-positive rest volume|do not match"),
    ("skin_faces", lambda a: a + 10_000_000, "outside"),
    ("vertex_body", lambda a: np.where(a >= 0, 999, a), "body index"),
    ("edges", lambda a: a[:, :1], "shape"),
])
def test_inconsistent_arrays(asset, field, mutate, message):
    import dataclasses

    bad = dataclasses.replace(asset, **{field: mutate(getattr(asset, field))})
    with pytest.raises(ph.AssetError, match=message):
        validate_asset(bad)
