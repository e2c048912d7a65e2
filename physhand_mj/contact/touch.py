"""Touch damping (``Config.tuning.touch_damping``): the skin an object pushed comes to rest.

A contact stage moves penetrating skin out of the objects by position (Eq. 9, the features); the
substep's end turns every move into velocity (v = (x - x^i) / h, Algorithm 1 line 15), so a pushed
vertex leaves the stage with the push's speed. Held against a thin wall's rim or a star prism's
points, skin can swing 8-18 mm a frame without settling, and the held frames' residue follows the
swing (docs/contact.md "Held contact at rest"). After each stage this takes a share of the velocity
of every skin vertex an object pushed in the frame (``PushSums.vertex_obj``), as the substep's end
will read it: x^i moves so that v keeps the rigid velocity the vertex's carrier bone gives it over
the substep and keep = exp(-dt / touch_damping) of the rest, dt the time since the substep the
last stage damped, as the solver's schedule recorded them (skin
riding a moving finger is not held back; only its motion relative to the bone is damped). Positions
are untouched; with ``two_way`` the exchange's own ``contact_damping`` acts instead.
"""

from __future__ import annotations

import math

import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.kernel
def damp_touched(vertex_obj: wp.array(dtype=int), x: wp.array(dtype=wp.vec3), keep: float,
                 vertex_carrier: wp.array(dtype=int), body_sub: wp.array2d(dtype=wp.transform),
                 body_pose: wp.array2d(dtype=wp.transform), substep: int, x_prev: wp.array(dtype=wp.vec3)):
    """x^i of each vertex an object pushed this frame (vertex_obj >= 0) moved so that the substep's
    velocity (x - x^i) / h keeps the rigid velocity its carrier bone gives it over substep
    ``substep`` (body_sub[substep - 1] -> body_sub[substep]; the frame's start pose body_pose[0]
    before the first) and ``keep`` of the rest: skin that rides a moving finger is not held back."""
    i = wp.tid()
    if vertex_obj[i] < 0:
        return
    p = x_prev[i]
    ride = p
    b = vertex_carrier[i]
    if b >= 0:
        t0 = body_pose[0, b]
        if substep > 0:
            t0 = body_sub[substep - 1, b]
        ride = wp.transform_point(body_sub[substep, b], wp.transform_point(wp.transform_inverse(t0), p))
    xi = x[i]
    x_prev[i] = xi - (ride - p) - (xi - ride) * keep


class TouchDamping:
    """The recording side of ``Config.tuning.touch_damping`` for one contact: after each recorded
    stage, :func:`damp_touched` with the keep for the time since the stage before it damped (the
    frame's first stage: since the last frame's last, which damped its last substep). Off (nothing
    recorded) at 0 and with ``two_way``, whose exchange damps its own contacts (``contact_damping``).
    ``keeps``: the keep of each stage the last recorded frame damped (for checks)."""

    def __init__(self, config):
        self.tau = 0.0 if config.two_way else float(config.touch_damping)
        self.keeps: list = []
        self._damped = -1  # the substep the last recorded stage damped

    def begin_frame(self) -> None:
        """A frame's recording starts."""
        self._damped, self.keeps = -1, []

    def record(self, rec, model, state, vertex_obj, substep: int, substep_dt: float) -> None:
        """After the stage in substep ``substep`` (``substep_dt`` s each): the pushed skin's motion
        relative to its bone damped over the substeps since the last stage damped."""
        if self.tau <= 0.0:
            return
        keep = touch_keep(self.tau, (substep - self._damped) * substep_dt)
        self._damped = substep
        self.keeps.append(keep)
        if keep < 1.0:
            rec.launch(damp_touched, vertex_obj.shape[0], [vertex_obj, state.x, keep, model.vertex_carrier,
                                                           state.body_sub, state.body_pose, int(substep)],
                       [state.x_prev])


def touch_keep(touch_damping: float, dt: float) -> float:
    """The share of a touched vertex's motion relative to its bone that a stage keeps, ``dt`` (s)
    after the substep the last stage damped: exp(-dt / touch_damping); 1 (nothing to do) when off or
    when no time passed (a second stage in the same substep, Placement.BOTH)."""
    if touch_damping <= 0.0 or dt <= 0.0:
        return 1.0
    return math.exp(-dt / touch_damping)
