"""The bone poses going into a frame, a :class:`PoseInput` the :class:`~physhand_mj.solver.solver.Solver`
holds (``Solver.poses``; the solver's pose methods call it): their checks (``pose_rows``), the next
frame's end poses (``set_body_poses``, ``set_body_pose_rows``), the fast-motion warning, and the
upload: two pinned host buffers used in turn, one of which ``stage_pose_rows`` fills while a frame
in flight still copies from the other (BatchedHands.submit).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.types import State


class PoseInput:
    """A solver's bone poses going in: reads its model, config, contact and regions (None: none); the
    methods that must not run while a frame of the state is in flight take the state in flight
    (``in_flight``: None when none; Solver.launch to Solver.finish)."""

    def __init__(self, model, config, contact, regions, pinned: bool):
        self.model, self.config, self.contact, self.regions = model, config, contact, regions
        n_bodies = model.n_bodies
        # the upload buffers ([frame start, frame end] rows), one per frame in turn: a frame in flight
        # copies from one while the next frame's poses go into the other (stage_pose_rows)
        self.pins = [wp.empty((2, n_bodies), dtype=wp.transform, device="cpu", pinned=pinned) for _ in range(2)]
        self._pins_np = [p.numpy() for p in self.pins]  # (their numpy views, made once: ~10 us each)
        self._pin = 0  # the buffer the next launch uploads from
        self._rows_set = None  # the rows set_body_pose_rows last took (a staged upload names them)
        self._staged = None  # the last stage_pose_rows token (launch takes only that one)
        self._warned_fast = False
        self.warn_fast_motion = True  # warn (once) when a bone outruns Config.contact_frame_margin in a frame

    def set_body_poses(self, state: State, pos: np.ndarray, quat: np.ndarray, in_flight: State | None) -> None:
        """Bone poses at the end of the next frame: pos (B, 3) m, quat (B, 4) w x y z, in the
        solver's world frame, ordered as ``model.body_names``. The skeleton moves there during the
        frame (interpolated per substep)."""
        self._not_in_flight(state, in_flight)
        self.pose_rows(pos, quat, out=state.pose_host[1])  # (written in place: batches, W x the bones a frame)
        state.pose_fresh = True
        self._rows_set = None

    @staticmethod
    def _not_in_flight(state: State, in_flight: State | None) -> None:
        """The next frame's poses may not be written while this state's frame is in flight: its
        ``finish`` still reads that frame's end poses (the sleep test)."""
        if in_flight is not None and in_flight is state:
            raise RuntimeError("a frame of this state is in flight (Solver.launch): Solver.finish(state) before "
                               "setting the next frame's poses")

    def pose_rows(self, pos: np.ndarray, quat: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """:meth:`set_body_poses`' checks and conversion without a state: (B, 7) float32 rows [p, q x y z
        w], the quaternions normed, into ``out`` when given. (BatchedHands.submit checks the next
        frame's poses while the device runs this one, then :meth:`set_body_pose_rows`.)"""
        pos = np.asarray(pos, dtype=np.float64)
        quat = np.asarray(quat, dtype=np.float64)
        b = self.model.n_bodies
        if pos.shape != (b, 3) or quat.shape != (b, 4):
            raise ValueError(f"bone poses must be ({b}, 3) positions and ({b}, 4) quaternions, "
                             f"got {pos.shape} and {quat.shape}")
        # (batches: W x the bones every frame, in series with the GPU: one sum each instead of a mask,
        # the squared norms in one pass; the exact test only to name the bones)
        n2 = np.einsum("ij,ij->i", quat, quat)
        with np.errstate(over="ignore"):  # (a huge finite sum only sends it to the exact test)
            finite = np.isfinite(pos.sum()) and np.isfinite(n2.sum())
        if not finite:
            if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
                from physhand_mj.types import SolverError

                bad = sorted({self.model.body_names[i] for i in np.flatnonzero(
                    ~(np.isfinite(pos).all(1) & np.isfinite(quat).all(1)))})
                raise SolverError(f"non-finite pose for bones {bad}: fix the MuJoCo state (qpos) first")
            n2 = None  # (finite but huge: the sums overflowed)
        norm = (np.sqrt(n2) if n2 is not None else np.linalg.norm(quat, axis=1))[:, None]
        if np.any(norm < 1e-9):
            from physhand_mj.types import SolverError

            raise SolverError("a bone quaternion has zero length")
        end = out if out is not None else np.empty((b, 7), np.float32)  # [p, q x y z w]
        end[:, :3] = pos
        np.divide(quat[:, 1:], norm, out=end[:, 3:6], casting="unsafe")
        np.divide(quat[:, :1], norm, out=end[:, 6:], casting="unsafe")
        return end

    @staticmethod
    def _check_rows(state: State, rows: np.ndarray) -> None:
        if np.shape(rows) != state.pose_host[1].shape:
            raise ValueError(f"pose rows must be {state.pose_host[1].shape} (Solver.pose_rows), got {np.shape(rows)}")

    def set_body_pose_rows(self, state: State, rows: np.ndarray, in_flight: State | None) -> None:
        """The next frame's end poses as :meth:`pose_rows` made them (checked and normed)."""
        self._not_in_flight(state, in_flight)
        self._check_rows(state, rows)
        state.pose_host[1] = rows
        state.pose_fresh = True
        self._rows_set = rows

    def set_rows_late(self, state: State, rows: np.ndarray, staged, in_flight: State | None) -> bool:
        """:meth:`set_body_pose_rows` for a launch taking ``staged`` (:meth:`stage_pose_rows`' token),
        where that token holds these very ``rows`` and takes the launch's fast-motion check: the rows
        are set now but go into ``state.pose_host`` only with :meth:`rows_landed`, after the frame is
        queued (the upload buffer already holds them; at W = 4,096 worlds the host copy takes ~0.5 ms,
        which would otherwise lie between one frame's end and the next one's launch). False (nothing
        set) where the token does not fit: the caller sets the rows as usual."""
        if not (self._token_fits(staged, state, rows) and (staged[3] is not None or not self._checks_jump())):
            return False
        self._not_in_flight(state, in_flight)
        self._check_rows(state, rows)
        state.pose_fresh = True
        self._rows_set = rows
        return True

    def _token_fits(self, staged, state: State, rows) -> bool:
        """Whether ``staged`` is the last token staged, for ``state``, in the buffer the next launch
        uploads from, holding these very ``rows`` (no per-region sleeping: it stages nothing)."""
        return (staged is not None and staged is self._staged and staged[0] is state and staged[1] == self._pin
                and rows is not None and staged[2] is rows and self.regions is None)

    @staticmethod
    def rows_landed(state: State, rows: np.ndarray) -> None:
        """After a launch whose rows :meth:`set_rows_late` set: the frame's end poses into the host's
        [start, end] rows, as the launch leaves them (both the frame's end)."""
        state.pose_host[1] = rows
        state.pose_host[0] = rows

    def stage_pose_rows(self, state: State, rows: np.ndarray, in_flight: State | None):
        """While a frame of ``state`` is in flight, fill the next frame's upload buffer with its start
        (the frame in flight's end) and ``rows`` (its end, :meth:`pose_rows`), so that the host copy
        leaves the time between that frame's end and the next one's launch. Returns a token for
        :meth:`Solver.launch` (``staged=``), which takes the buffer as it is only if this is the last token
        staged and :meth:`set_body_pose_rows` was given this very ``rows`` array after :meth:`Solver.finish`,
        and fills the buffer itself otherwise; ``rows`` must not change in between (the buffer holds
        their copy). None (nothing to stage) when no frame of ``state`` is in flight or per-region
        sleeping is on. (BatchedHands.submit: fresh rows each frame, staged once.)"""
        self._staged = None
        if in_flight is None or in_flight is not state or self.regions is not None:
            return None
        self._check_rows(state, rows)
        buf = self._pins_np[self._pin]  # (the frame in flight uploads from the other one)
        buf[0] = state.pose_host[0]  # (launch moved the frame in flight's end there; finish leaves it)
        buf[1] = rows
        # (the fast-motion check's largest bone move too, for launch)
        self._staged = (state, self._pin, rows, self._bone_jump(buf[0], buf[1]) if self._checks_jump() else None)
        return self._staged

    def _checks_jump(self) -> bool:
        """Whether :meth:`Solver.launch` checks how far a bone moves in the frame (contact, the warning not given)."""
        return (self.contact is not None and self.warn_fast_motion and not self._warned_fast
                and bool(self.model.n_bodies))

    @staticmethod
    def _bone_jump(p0: np.ndarray, p1: np.ndarray) -> float:
        """The largest distance a bone's origin moves from pose rows ``p0`` to ``p1`` (m)."""
        d = p1[:, :3] - p0[:, :3]
        return float(np.sqrt(np.max(np.einsum("ij,ij->i", d, d))))

    def frame_poses_in(self, state: State, staged):
        """:meth:`Solver.launch`'s poses: the frame's end settled (the start again without a new pose), the
        fast-motion warning, and the upload buffer filled unless ``staged`` (:meth:`stage_pose_rows`'
        token) is the last one staged for this state and these rows. Returns (the buffer, the
        frame's (start, end) rows on the host: the start a view of the buffer, filled again two
        frames on, after this frame's finish; the end until the next set_body_poses)."""
        staged = staged if self._token_fits(staged, state, self._rows_set) and state.pose_fresh else None
        self._staged = None
        if not state.pose_fresh:  # (without a new pose the bones stay)
            state.pose_host[1] = state.pose_host[0]
        elif self._checks_jump():
            jump = staged[3] if staged is not None and staged[3] is not None else self._bone_jump(
                state.pose_host[0], state.pose_host[1])
            if jump > self.config.contact_frame_margin - self.config.contact_margin:
                from physhand_mj.warn import warn_user

                self._warned_fast = True
                warn_user(f"a bone moved {jump * 1e3:.1f} mm in one frame, more than "
                          f"Config.contact_frame_margin - contact_margin "
                          f"({(self.config.contact_frame_margin - self.config.contact_margin) * 1e3:.1f} mm): "
                          f"contacts may be missed; raise contact_frame_margin or use shorter frames")
        pin = self.pins[self._pin]
        buf = self._pins_np[self._pin]
        if staged is None:
            buf[:] = state.pose_host  # (else stage_pose_rows filled it while the frame before ran)
        self._pin ^= 1
        self._rows_set = None
        return pin, (buf[0], state.pose_host[1])
