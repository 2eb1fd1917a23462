"""The one table from solver names (CLI, `fit(solver="lm")`) to optimistix solver objects."""

from __future__ import annotations

import optimistix as optx

__all__ = ["SOLVERS", "make_solver", "solver_name"]

# name -> (constructor, description). Every constructor takes rtol and atol.
SOLVERS = {
    "lm": (optx.LevenbergMarquardt, "Levenberg-Marquardt, trust region by damping (default)"),
    "gauss-newton": (optx.GaussNewton, "Gauss-Newton, undamped; fast near the optimum, fragile far from it"),
    "dogleg": (optx.Dogleg, "Powell's dogleg trust-region method"),
    "indirect-lm": (optx.IndirectLevenbergMarquardt, "Levenberg-Marquardt with an iterative damping search"),
    "bfgs": (optx.BFGS, "BFGS quasi-Newton minimiser of the summed squares"),
}


def make_solver(solver, rtol: float, atol: float):
    """Turn a solver name into an optimistix solver; pass a solver object through unchanged.

    Arguments:
        solver: a name from `SOLVERS` or any `optimistix.AbstractLeastSquaresSolver` / `AbstractMinimiser`.
        rtol, atol: tolerances for a named solver.

    Returns:
        The solver object.

    Raises:
        ValueError: for an unknown name.
    """
    if isinstance(solver, str):
        try:
            constructor = SOLVERS[solver][0]
        except KeyError:
            raise ValueError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)} or pass an "
                             "optimistix solver object") from None
        return constructor(rtol=rtol, atol=atol)
    if isinstance(solver, (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)):
        return solver
    raise ValueError(f"solver must be a name ({', '.join(SOLVERS)}) or an optimistix least-squares solver or "
                     f"minimiser, got {type(solver).__name__}")


def solver_name(solver) -> str:
    """A readable name of a solver object: its table name when it came from the table, else its class name."""
    for name, (constructor, _) in SOLVERS.items():
        if type(solver) is constructor:
            return name
    return type(solver).__name__
