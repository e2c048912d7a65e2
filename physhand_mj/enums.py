"""The closed sets of the solver's options and data: a vertex's layer, the constraint scheme, the
object shapes, the contact strategy and placement, the non-finite policy (re-exported by
:mod:`physhand_mj.types`)."""

from __future__ import annotations

import enum


class Layer(enum.IntEnum):
    """Layer of a vertex of the layered body, outermost last.

    SKELETON vertices lie on bone surfaces and are moved kinematically by their MuJoCo body
    (inverse mass 0); FLESH vertices are interior tet nodes; SKIN vertices form the outer surface,
    which collides and is rendered.
    """

    SKELETON = 0
    FLESH = 1
    SKIN = 2


class Scheme(enum.IntEnum):
    """How constraint projections run in parallel (see docs/solver.md for the measurements).

    JACOBI: every constraint of a family at once from the same positions; corrections are summed per
      vertex, averaged over the vertex's constraint count and scaled by ``Config.tuning.relaxation``.
      Few launches (one per family), so it suits GPUs and CUDA graphs.
    COLORED: graph-coloured Gauss-Seidel; constraints of one colour share no movable vertex, so each
      colour is projected in place, in sequence (one launch per colour).
    """

    JACOBI = 0
    COLORED = 1


class GeomType(enum.IntEnum):
    """Object shapes with a signed distance function (physhand_mj.contact.sdf). Sizes follow MuJoCo:
    sphere (r), capsule (r, half length along z), ellipsoid (radii), cylinder (r, half height along
    z), box (half extents), plane (the half-space z <= 0 of its frame), mesh (a wp.Mesh in the geom
    frame), cone (base radius, height; tip at the origin pointing +z; not a MuJoCo geom: the paper's
    cone experiment)."""

    NONE = 0
    PLANE = 1
    SPHERE = 2
    CAPSULE = 3
    ELLIPSOID = 4
    CYLINDER = 5
    BOX = 6
    MESH = 7
    CONE = 8


class Strategy(enum.IntEnum):
    """Where a skin triangle's decision point comes from (paper section 3.3; section 4.2 baselines)."""

    NONE = 0  # no contact
    VERTEX = 1  # the 3 vertices and 3 edge midpoints (Fuhrmann et al. 2003)
    OPT = 2  # Frank-Wolfe over the barycentric simplex from the centroid (Macklin et al. 2020)
    MULTIRES = 3  # the paper's multi-resolution querying (Algorithm 2)


class Placement(enum.IntEnum):
    """Where in a substep the contact correction runs (paper Algorithm 1 puts it before the
    constraints, line 6)."""

    BEFORE = 1  # after the prediction, before the constraints (Algorithm 1)
    AFTER = 2  # after the constraints, before the velocity update
    BOTH = 3


class NonFinite(enum.IntEnum):
    """What a step does when a vertex position turns non-finite (NaN/inf)."""

    RECOVER = 0  # keep the vertex's last finite position, zero its velocity, count it in metrics
    RAISE = 1  # raise SolverError after the frame (state left at the last finite positions)


def enum_field(cls, value, name: str):
    """``value`` as a member of ``cls``: the member, its int value or its name (any case); a clear
    ValueError naming the Config field and its choices otherwise."""
    if isinstance(value, str) and value.upper() in cls.__members__:
        return cls[value.upper()]
    try:
        return cls(value)
    except (ValueError, TypeError):
        choices = ", ".join(f"{m.name} ({m.value})" for m in cls)
        raise ValueError(f"Config.{name}={value!r} is not a {cls.__name__}; use one of {choices}, "
                         f"as physhand_mj.{cls.__name__}.<NAME>, its number or its name") from None

