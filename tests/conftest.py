import os

os.environ.setdefault("MUJOCO_GL", "osmesa")

import pytest  # noqa: E402

import physhand_mj as ph  # noqa: E402


@pytest.fixture(scope="session")
def asset():
    return ph.load_asset()
