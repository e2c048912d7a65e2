"""Greedy graph colouring of constraints for the coloured Gauss-Seidel scheme.

Two constraints conflict when they share a movable vertex (inverse mass > 0); kinematic skeleton
vertices are never written, so they do not create conflicts. Constraints of one colour can then be
projected in place in parallel.
"""

from __future__ import annotations

import numpy as np


def greedy_colors(ids: np.ndarray, movable: np.ndarray) -> np.ndarray:
    """Colour of each row of ``ids`` (C, k), first-fit in row order; vertices where ``movable`` is
    False are ignored. Returns (C,) int32 colours 0..n_colors-1."""
    used = [0] * len(movable)  # per vertex: bitmask of colours already taken by its constraints
    colors = np.empty(len(ids), dtype=np.int32)
    mov = movable.tolist()
    for j, row in enumerate(ids.tolist()):
        verts = [v for v in row if mov[v]]
        taken = 0
        for v in verts:
            taken |= used[v]
        c = (~taken & (taken + 1)).bit_length() - 1  # lowest free colour
        bit = 1 << c
        for v in verts:
            used[v] |= bit
        colors[j] = c
    return colors


def color_ranges(colors: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """A stable order sorting rows by colour, and the [start, end) range of each colour in it."""
    order = np.argsort(colors, kind="stable")
    counts = np.bincount(colors) if len(colors) else np.zeros(0, dtype=int)
    ends = np.cumsum(counts)
    return order, [(int(e - c), int(e)) for c, e in zip(counts, ends)]
