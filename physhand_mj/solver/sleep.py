"""Whole-hand sleeping, a :class:`Sleep` the :class:`~physhand_mj.solver.solver.Solver` holds
(``Solver.sleep``; physhand_mj/solver/activity.py has the concept and its measurements): the bone
tests on the host (a hand moving as one rigid body, no object near), the sleeping frame (one launch
carries every vertex with its bone), the CUDA host-side box test that skips the broadphase run
ahead, and waking.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from physhand_mj.solver import integrate
from physhand_mj.rotations import pose_turn, quat_to_mat
from physhand_mj.types import State

SLEEP_TURN = math.radians(2.0)  # rad: the first bone's turn since the hand fell asleep that wakes it
# m, the sleeping skin's box (Sleep.asleep_and_alone) is grown by this: its bones may drift up to
# Config.tuning.sleep_bone_motion (10 um at a 0.1 m lever) from one rigid motion before the hand wakes
SLEEP_BOX_SLACK = 1.0e-3


def frame_rigid(start: np.ndarray, end: np.ndarray, tol: float) -> bool:
    """No bone moved relative to the others by more than ``tol`` (m) between two (B, 7) pose sets
    (bones at rest: equal arrays, no numpy work)."""
    return bool(np.array_equal(start, end) or bone_motion(start, end) <= tol)


def bone_motion(start: np.ndarray, end: np.ndarray, lever: float = 0.1) -> float:
    """How far (m) the bones move relative to the first one over a frame: for poses (B, 7) [p, q
    x y z w] at its start and end, the largest of :func:`bone_motions`. 0 for a hand moving as one
    rigid body."""
    if start.shape[0] < 2:
        return 0.0
    return float(np.max(bone_motions(start, end, lever)))


def bone_motions(start: np.ndarray, end: np.ndarray, lever: float = 0.1) -> np.ndarray:
    """Per bone (B,), m: the distance between where its own motion and the first bone's motion take
    its origin, plus the angle between their rotations times ``lever`` (m, a hand's size), for poses
    (B, 7) [p, q x y z w] at the start and end of a motion (the first bone's own: 0)."""
    if start.shape[0] < 2:
        return np.zeros(start.shape[0])
    p0, p1 = start[:, :3].astype(np.float64), end[:, :3].astype(np.float64)
    r0, r1 = quat_to_mat(start[:, [6, 3, 4, 5]]), quat_to_mat(end[:, [6, 3, 4, 5]])  # (x y z w -> w x y z)
    m = r1 @ np.swapaxes(r0, -1, -2)  # each bone's rotation over the frame
    root = m[0] @ (p0 - p0[0]).T  # where the first bone's motion takes every origin (3, B)
    dist = np.linalg.norm(root.T + p1[0] - p1, axis=1)
    rel = m @ m[0].T  # rotation of each bone relative to the first's
    axis = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], -1)
    ang = np.arctan2(0.5 * np.linalg.norm(axis, axis=1), 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1.0))
    return dist + ang * lever


class Sleep:
    """A solver's whole-hand sleeping: its tests, its recorded sleeping frames and their launch. Reads
    the solver's model, config, activity gates (:class:`~physhand_mj.solver.activity.Activity`), contact
    and regions (None: none); the solver passes what a frame needs (its replay, its tail ops, the
    guard's host copy, the ops run ahead) to :meth:`launch` and :meth:`finish`."""

    def __init__(self, model, config, device, activity, contact, regions):
        self.model, self.config, self.device = model, config, device
        self.activity, self.contact, self.regions = activity, contact, regions
        self.ops: dict[tuple, list] = {}  # the recorded sleeping frames, per (frame key, pose buffer)
        self.alone_key = None  # (sleep box, first bone's poses, object poses) of the last 'nothing near' test
        self.launched = None  # (frame key, ops counted, broadphase ran ahead) of the frame launch queued

    def forget(self) -> None:
        """Drop the recorded sleeping frames (the solver records its frames again)."""
        self.ops.clear()

    def may_sleep(self, state: State) -> bool:
        """Settled for Config.tuning.sleep_frames frames and no object near (this frame's test: the CPU's
        host box test, or the frame broadphase run ahead on CUDA; no objects at all: nothing near)."""
        cfg, act = self.config, self.activity
        if cfg.sleep_speed <= 0 or state.still < cfg.sleep_frames:
            return False
        if self.contact is None:
            return True
        if act.gate_ahead:
            return not act.open1
        return act.enabled and act.objects_near == 0

    def asleep_and_alone(self, state: State, poses) -> bool:
        """CUDA, a hand that slept last frame and may sleep on: is every object farther than
        Config.contact_frame_margin from its skin? Decided on the host, without the frame broadphase
        run ahead and its sync. Asleep, the bones move as one rigid body (within
        Config.tuning.sleep_bone_motion of it since the hand fell asleep, else it wakes) and the skin rides
        with them, so the sleeping skin's box in the first bone's frame (taken once when it fell
        asleep, ``State.sleep_box``, grown by SLEEP_BOX_SLACK), placed at the frame's start and end
        poses of that bone, bounds the skin all frame; the objects' bounding spheres are tested
        against the world box around those two (activity.objects_near, the CPU's level-0 test).
        False sends the frame down the usual path (broadphase ahead, then sleep or not). One world.
        """
        from physhand_mj.solver.activity import objects_near

        box = state.sleep_box
        if box is None or self.contact is None or not self.activity.gate_ahead or not self.settled(state):
            return False
        objs = self.contact.objects._host["pose"]
        key = (id(box), poses[0][0].tobytes(), poses[1][0].tobytes(), objs.tobytes())
        if key == self.alone_key:  # this box, its bone and every object where the last test left them
            self.activity.objects_near = 0
            return True
        corners = []
        for pose in poses:
            p, q = pose[0, :3].astype(np.float64), pose[0, [6, 3, 4, 5]].astype(np.float64)
            corners.append(box @ quat_to_mat(q).T + p)
        world = np.concatenate(corners)
        near = objects_near(self.contact.objects, world.min(axis=0), world.max(axis=0),
                            self.config.contact_frame_margin)
        self.activity.objects_near = near
        self.alone_key = key if near == 0 else None
        return near == 0

    def take_box(self, state: State) -> None:
        """CUDA, the first sleeping frame: the skin's 8 box corners in the first bone's frame at the
        frame's end pose (see :meth:`asleep_and_alone`); one copy of the skin to the host."""
        m = self.model
        if not (self.activity.gate_ahead and self.contact is not None and m.n_bodies
                and int(getattr(m, "worlds", 1)) == 1):
            return
        x = state.x.numpy()[: m.n_skin].astype(np.float64)
        pose = state.pose_host[0][0].astype(np.float64)  # the frame's end pose (step moved it up)
        local = (x - pose[:3]) @ quat_to_mat(pose[[6, 3, 4, 5]])  # R^T (x - p), row-wise
        lo, hi = local.min(axis=0) - SLEEP_BOX_SLACK, local.max(axis=0) + SLEEP_BOX_SLACK
        pick = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(8, 3)
        state.sleep_box = np.where(pick == 1, hi, lo)
        self.alone_key = None  # a new box: test it afresh (an old key could name a freed box's id)

    def launch(self, state: State, key, replay, tail: list, guard_host, pin: int = -1, upload=None) -> None:
        """One launch: every vertex rides with its carrier bone, at rest; the report buffers zeroed
        (CUDA: one captured graph, which with ``upload`` (a pose buffer Solver.launch left, its index
        ``pin``) also uploads the frame's poses first, and copies the guard back to ``guard_host``).
        ``replay(ops, key)``: the solver's frame replay (Solver.replay); ``tail``: the ops ending
        every frame (Solver.set_frame_tail). :meth:`finish` reports it."""
        frame_key, key = key, key + (pin,)  # (the frame's key names its broadphase ahead; one graph per buffer)
        ops = self.ops.get(key)
        if ops is None:
            m, d = self.model, self.device
            ops = [] if upload is None else [lambda: wp.copy(state.body_pose, upload)]
            ops.append(state.guard.zero_)
            if self.contact is not None:
                self.contact.begin_frame(ops)
                ops.append(self.contact.counters.zero_)  # (CUDA: also when the broadphase did not run ahead)
                if self.contact.holds:  # (Config.contact_linear: no plane outlives a frame without contact)
                    ops.append(self.contact.hold.data.state.zero_)
            cmd = wp.launch(integrate.carry_asleep, m.n_vertices,
                            inputs=[m.vertex_carrier, m.vertex_world, state.body_pose, float(self.config.frame_dt)],
                            outputs=[state.x, state.v, state.x_prev, state.x_safe, state.guard], device=d,
                            record_cmd=True)
            ops.append(cmd.launch)
            ops += tail
            ops.append(lambda: wp.copy(guard_host, state.guard))
            self.ops[key] = ops
        ahead = self.activity.gate_ahead and state.sleep_box is None  # (CUDA: the broadphase ran ahead)
        replay(ops, key + ("asleep",))
        # (ops_run counts the frame's launches and memsets as before: not the pose upload and guard copy
        # the graph took over, nor the planes' reset)
        extra = 1 + int(upload is not None) + int(self.contact is not None and self.contact.holds)
        self.launched = (frame_key, len(ops) - extra, ahead)

    def finish(self, state: State, ahead_ops: dict) -> dict:
        """The sleeping frame :meth:`launch` queued: its sync, the state's clock, the box taken on its
        first frame; returns its activity report (Solver.last_activity; ``ahead_ops``: the solver's
        broadphase ops run ahead, per frame key)."""
        key, n_ops, ahead = self.launched
        wp.synchronize_device(self.device)
        state.time += self.config.frame_dt
        state.frames += 1
        if state.sleep_box is None:
            self.take_box(state)
        ahead = len(ahead_ops.get(key, ())) * int(ahead)
        near = self.activity.objects_near if self.contact is not None else 0
        return dict(objects_near=near, triangles_frame=0, triangles_stage=0, triangles_tested=0,
                    features_listed=0, ops_run=n_ops + ahead, contact_ops_run=ahead)

    def wake(self, state: State) -> None:
        """Forget that ``state`` had settled (it sleeps again after Config.tuning.sleep_frames still frames)."""
        state.still = 0
        state.sleep_onset = state.sleep_box = None
        if self.regions is not None:
            self.regions.wake_all()
        if self.contact is not None:  # (Config.contact_linear: a woken or reset hand holds on no old plane)
            self.contact.forget_planes()

    def settled(self, state: State) -> bool:
        return self.config.sleep_speed > 0 and state.still >= self.config.sleep_frames

    def bones_still(self, state: State) -> bool:
        """The sleep test's bone conditions for this frame (poses on the host, before the upload):
        no bone moves relative to the others by more than Config.tuning.sleep_bone_motion in the frame, and,
        while asleep, since it fell asleep; nor has the first bone turned by more than SLEEP_TURN
        (gravity turns in the hand) or changed its velocity by more than Config.sleep_speed. Falling
        short of any resets the settle count (the hand must settle again)."""
        cfg = self.config
        p0, p1 = state.pose_host[0], state.pose_host[1]
        if not frame_rigid(p0, p1, cfg.sleep_bone_motion):
            state.still = 0
            return False
        if not len(p0):
            return True
        vel = (p1[0, :3].astype(np.float64) - p0[0, :3]) / cfg.frame_dt
        if state.sleep_onset is None:  # falls asleep this frame (if nothing else keeps it awake)
            state.sleep_onset = (p0.copy(), vel)
            return True
        onset, vel0 = state.sleep_onset
        moved = not np.array_equal(onset, p1)  # bones where they fell asleep (a still hand): no turn, no drift
        if np.linalg.norm(vel - vel0) > cfg.sleep_speed or (moved and (
                bone_motion(onset, p1) > cfg.sleep_bone_motion or pose_turn(onset[0], p1[0]) > SLEEP_TURN)):
            state.still = 0
            state.sleep_onset = state.sleep_box = None
            return False
        return True
