"""Warnings that point at the user's line.

A warning raised deep inside the package (a frame's report, a batch's pipeline, a Config check run
by the solver) would name a line of physhand_mj with a fixed ``stacklevel``, and which line depends
on the path that called it (``Solver.step``, ``BatchedHands.submit``, a rollout). :func:`warn_user`
names the first caller outside the package (``physhand_mj``, its ``physhand_dmc`` and
``physhand_myosuite`` plugins, and dm_control, whose environments call them) instead, as
``warnings.warn(..., skip_file_prefixes=...)`` does from Python 3.12 on. So a filter that picks
these warnings by ``module`` sees the caller's module: filter by ``message`` or ``category``.
"""

from __future__ import annotations

import os
import sys
import warnings

# the package's own folder (this file's), its plugins' and the frameworks that call them (a
# dm_control environment's step): frames there are not the user's
_OURS = os.path.dirname(os.path.abspath(__file__)) + os.sep
_CALLERS = tuple(os.sep + name + os.sep for name in ("physhand_dmc", "physhand_myosuite", "dm_control"))


def _ours(filename: str) -> bool:
    path = os.path.abspath(filename)
    return path.startswith(_OURS) or any(name in path for name in _CALLERS)


def warn_user(message: str, category: type[Warning] = RuntimeWarning) -> None:
    """``warnings.warn(message, category)`` attributed to the first frame outside the package (the
    last frame of the stack if every frame is the package's)."""
    level, frame = 2, sys._getframe(1)  # (level 1 is this function; 2 its caller)
    # (a dataclass's generated __init__, which runs Settings' checks, has no file: "<string>")
    while frame.f_back is not None and (_ours(frame.f_code.co_filename)
                                        or (frame.f_code.co_filename.startswith("<") and frame.f_code.co_name == "__init__")):
        frame = frame.f_back
        level += 1
    warnings.warn(message, category, stacklevel=level)
