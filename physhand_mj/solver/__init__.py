"""XPBD solver for the layered body (paper section 3.2, Algorithm 1).

``make_model(asset, config)`` builds the immutable Model; ``Solver(model, config)`` owns the frame;
``Solver.make_state`` preallocates a State; ``Solver.set_body_poses`` + ``Solver.step`` advance it.
"""

from physhand_mj.solver.model import make_model
from physhand_mj.solver.solver import Solver, SolverError

__all__ = ["Solver", "SolverError", "make_model"]
