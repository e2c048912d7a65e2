"""XPBD solver for the layered body (paper section 3.2, Algorithm 1).

``make_model(asset, config)`` builds the immutable Model; ``Solver(model, config)`` owns the frame;
``Solver.make_state`` preallocates a State; ``Solver.set_body_poses`` + ``Solver.step`` advance it.

What every constraint kernel (edge.py, tet.py, smooth.py) computes:

For constraint j with gradient g_i at vertex i (Algorithm 1 of the paper):

    A      = sum_i w_i |g_i|^2 + alpha~,      alpha~ = alpha / h^2           (lines 5, 8)
    dlam   = -(C(x) + alpha~ lam_j) / A                                       (line 9)
    dx_i   = w_i g_i dlam,  lam_j += dlam                                     (lines 10-12)

``dx_i`` is added with ``wp.atomic_add(delta, i, dx_i)``. The scheme decides what ``delta`` is: the
Jacobi accumulator (averaged and applied by integrate.apply_jacobi), or the position array ``x``
itself for coloured Gauss-Seidel, where no two constraints of a colour share a movable vertex, so the
add is an in-place update. Kinematic vertices have w = 0 and receive zero. The three kernels are
made from one definition (solver/xpbd.py's ``constraint_kernel``, the family's correction and dlam's
``multiplier_step`` inlined); no shared ``wp.func`` takes arrays: on Warp's CPU backend such calls
made the tet kernel 1.8x slower (measured).
A constraint with A <= 1e-20 is degenerate and skipped; a non-finite result is caught by the velocity
update's guard (integrate.advance).
"""

from physhand_mj.solver.model import make_model
from physhand_mj.solver.solver import Solver
from physhand_mj.types import SolverError

__all__ = ["Solver", "SolverError", "make_model"]
