"""Fixtures of the stress suite (issue 14): the hand scene, and a record of each test's measured margins.

``PHYSHAND_STRESS_MARGINS=path.json`` makes the session write every test's margins (what it asserted,
the bound and the value measured) to ``path.json``; benchmarks/stress_margins.py runs the suite so.
"""

import json
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # stress_harness, also for `pytest tests/stress/x.py`

_MARGINS: dict = {}


@pytest.fixture(scope="session")
def scene():
    from stress_harness import HandScene

    return HandScene()


@pytest.fixture
def margins(request):
    """A dict the test fills with its measured margins (kept per test id)."""
    out: dict = {}
    yield out
    if out:
        _MARGINS[request.node.nodeid] = out


def pytest_sessionfinish(session, exitstatus):
    path = os.environ.get("PHYSHAND_STRESS_MARGINS")
    if path and _MARGINS:
        Path(path).write_text(json.dumps(_MARGINS, indent=1, sort_keys=True, default=float) + "\n")
