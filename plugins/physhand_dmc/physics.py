"""``SoftPhysics``: dm_control's ``mujoco.Physics`` with the soft hand running after every MuJoCo step.

- ``step(n)``: n times (MuJoCo step, then one SoftHand solver frame of ``model.opt.timestep``); a
  control step of n physics steps runs n soft frames. With ``Config.two_way`` each is a whole
  ``mj_step`` (not dm_control's legacy split step, which leaves data's kinematics at the step's
  end: two-way coupling moves a free object over the frame from the pose the step started at, and
  its wrenches change qpos / qvel after the step), then ``mj_step1`` once at the end, so data is in
  sync with the new qpos / qvel as after dm_control's own step.
- ``render(...)``: re-uploads the skin mesh into dm_control's cached MuJoCo render context when
  the skin moved since the last upload (``mujoco.mjr_uploadMesh``), so pixels show the deformed skin.
- ``soft``: the :class:`~physhand_dmc.sensing.SensedHand`; ``soft_sensor``: its pooled signals.
- ``timing``: accumulated seconds of MuJoCo steps and soft-hand frames (SoftHand keeps its stages).

The soft tissue is not part of ``get_state()`` / ``set_state()`` (dm_control's physics state is
MuJoCo's); ``copy()`` gives a Physics without the soft hand.
"""

from __future__ import annotations

import time

import mujoco
from dm_control import mujoco as dm_mujoco

from physhand_dmc.sensing import SensedHand


class SoftPhysics(dm_mujoco.Physics):
    """Physics of a scene holding a soft layered body (the hand, or pads on a gripper)."""

    _soft: SensedHand | None = None
    _skin_uploaded: bool = True

    def make_soft(self, config, *, asset=None, prefix: str = "", object_bodies=None,
                  settle_frames: int = 0) -> SensedHand:
        """Build the soft hand on this physics (bones and skin geom found in the model; contact only
        against the bodies named in ``object_bodies``)."""
        self._soft = SensedHand(self.model.ptr, self.data.ptr, config, asset=asset, prefix=prefix, object_bodies=object_bodies,
                                settle_frames=settle_frames)
        self._soft.attach_sensor()
        self._skin_uploaded = False
        self.timing = dict(mujoco=0.0, soft=0.0, steps=0)
        return self._soft

    @property
    def soft(self) -> SensedHand:
        if self._soft is None:
            raise RuntimeError("this Physics has no soft hand: build it with make_soft() (the suite's load() does)")
        return self._soft

    def reset_soft(self, settle_frames: int) -> None:
        """New episode: the soft tissue back to rest at the current bone pose, then settled."""
        self.soft.reset(settle_frames=settle_frames)
        self._skin_uploaded = False

    def step(self, nstep: int = 1) -> None:
        if self._soft is None:
            return super().step(nstep)
        tm = self.timing
        if self._soft.config.two_way:
            return self._step_two_way(nstep)
        for _ in range(nstep):
            t0 = time.perf_counter()
            super().step(1)
            t1 = time.perf_counter()
            self._soft.step()
            tm["mujoco"] += t1 - t0
            tm["soft"] += time.perf_counter() - t1
            tm["steps"] += 1
        self._skin_uploaded = False

    def _step_two_way(self, nstep: int) -> None:
        """``step`` with Config.two_way (see the module docstring): MuJoCo's whole step, then the soft
        frame, which reads the step's start from data and writes the skin's impulses into qvel (and a
        free object's pose into qpos); ``mj_step1`` at the end brings data's kinematics to the new state."""
        tm = self.timing
        m, d = self.model.ptr, self.data.ptr
        with self.check_invalid_state():
            for _ in range(nstep):
                t0 = time.perf_counter()
                mujoco.mj_step(m, d)
                t1 = time.perf_counter()
                self._soft.step()
                tm["mujoco"] += t1 - t0
                tm["soft"] += time.perf_counter() - t1
                tm["steps"] += 1
            mujoco.mj_step1(m, d)
        self._skin_uploaded = False

    def render(self, *args, **kwargs):
        if self._soft is not None and not self._skin_uploaded:
            ctx = self.contexts  # dm_control's cached GL + MuJoCo contexts (made on first use)
            with ctx.gl.make_current() as gl:
                gl.call(mujoco.mjr_uploadMesh, self.model.ptr, ctx.mujoco.ptr, self._soft.skin_mesh_id)
            self._skin_uploaded = True
        return super().render(*args, **kwargs)
