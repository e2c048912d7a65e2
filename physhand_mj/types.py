"""Closed sets and small value types shared across physhand_mj.

The solver's ``Model`` / ``State`` / ``Config`` split lands here with the XPBD solver; for now this
module holds the layer labels of the layered body (paper section 3.1).
"""

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
