"""Flesh attachment constraint, paper Eq. 4-5.

    C_att(x_f) = C_edge(x_f, x_s) = |x_f - x_s| - L,   x_s = argmin_{x_i in skeleton} |x_f - x_i|

Each flesh vertex is tied by an edge constraint (Eq. 2) to its nearest skeleton vertex, chosen once
at rest by the asset builder. Because Eq. 4 *is* an edge constraint, the solver appends these pairs
to the edge family and projects them with ``edge.solve_edges`` (one launch fewer per substep); this
module decides which pairs exist and with what compliance.
"""

from __future__ import annotations

import numpy as np

from physhand_mj.types import Config, Layer


def attachment_pairs(asset, config: Config) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, 2) (vertex, skeleton vertex) pairs, (A,) rest lengths (m), (A,) compliances (m/N).

    Flesh vertices always (when ``config.attachment``); skin vertices too with ``config.attach_skin``.
    """
    if not config.attachment:
        return np.zeros((0, 2), np.int32), np.zeros(0), np.zeros(0)
    layer = np.asarray(asset.layer)[asset.attach[:, 0]]
    keep = layer == Layer.FLESH
    if config.attach_skin:
        keep |= layer == Layer.SKIN
    rest = asset.attach_rest_length[keep]
    return asset.attach[keep], rest, np.full(len(rest), config.attach_compliance)
