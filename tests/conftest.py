import pytest

from physhand_mj.render import select_gl_backend

select_gl_backend()  # MUJOCO_GL as set, else EGL on NVIDIA machines, OSMesa, or a display: before mujoco loads

import physhand_mj as ph  # noqa: E402


@pytest.fixture(scope="session")
def asset():
    return ph.load_asset()
