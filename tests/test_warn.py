"""physhand_mj.warn.warn_user: a warning raised inside the package names the user's line, however deep
the package's own calls go (a Config check, a mesh repaired when it is added)."""

import warnings

import numpy as np
import pytest
import trimesh

import physhand_mj as ph
from physhand_mj.contact import Objects
from physhand_mj.types import GeomType
from physhand_mj.warn import warn_user


def _line_of(fn):
    """(file, line) the warnings raised by ``fn()`` are attributed to (all the same), and a message."""
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        fn()
    assert rec and len({(w.filename, w.lineno) for w in rec}) == 1, [(w.filename, w.lineno, str(w.message)) for w in rec]
    return rec[0].filename, rec[0].lineno, str(rec[0].message)


def test_a_warning_from_inside_names_the_callers_line():
    here = __file__
    f, line, msg = _line_of(lambda: ph.Config(frame_dt=0.01, substeps=1, max_substep=None).validate())
    assert f == here and "substeps" in msg, (f, line, msg)
    # the same check run deep inside the solver's set-up still names this line
    from physhand_mj.solver import Solver, make_model

    asset = ph.load_asset()
    cfg = ph.Config(frame_dt=0.01, substeps=1, max_substep=None)
    f, line, msg = _line_of(lambda: Solver(make_model(asset, cfg), cfg))
    assert f == here and "substeps" in msg, (f, line, msg)
    box = trimesh.creation.box((0.03, 0.03, 0.03))
    faces = np.asarray(box.faces)[:, ::-1].copy()  # every face turned inside out: repaired, with a warning
    objects = Objects("cpu", 1)
    f, line, msg = _line_of(lambda: objects.add(GeomType.MESH, None, vertices=box.vertices, faces=faces, name="box"))
    assert f == here, (f, line, msg)


def test_warn_user_counts_only_package_frames():
    """Called from outside the package (here), the warning names the caller itself."""
    with pytest.warns(RuntimeWarning, match="plain") as rec:
        warn_user("plain")
    assert rec[0].filename == __file__
