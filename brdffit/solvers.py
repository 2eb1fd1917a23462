"""The one table from solver names (CLI, `fit(solver="lm")`) to optimistix solver objects."""

from __future__ import annotations

import jax.numpy as jnp
import lineax as lx
import optimistix as optx

__all__ = ["SOLVERS", "make_solver", "coarse_solver", "solver_name", "working_tolerances"]

# Floors of the convergence tolerances in units of the working precision's machine epsilon: rounding makes
# successive float32 steps differ by a few ulps of the cost and of the parameters, so a float32 fit (run under
# `jax.enable_x64(False)`) with the float64 defaults would never meet them and end at max_steps. In float64 the
# floors (2.2e-14 and 2.2e-16) lie below the defaults and change nothing.
RTOL_FLOOR_EPS = 100.0
ATOL_FLOOR_EPS = 1.0

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


def _working_float():
    """`jnp.finfo` of JAX's default float type: float64 once brdffit is imported, float32 inside
    ``jax.enable_x64(False)``."""
    return jnp.finfo(jnp.result_type(float))


def coarse_solver(solver, rtol: float, atol: float):
    """The solver of a two-stage fit's coarse stage (`brdffit.fit.COARSE_SAMPLES` samples) for a named solver.

    For ``"lm"`` in float64 it is Levenberg-Marquardt whose damped step solves the normal equations
    (JᵀJ + λI) δ = −Jᵀr by Cholesky (lineax's ``Normal(Cholesky())``) instead of a QR factorisation of the
    stacked [J; √λ I] (optimistix's default): the same steps, 1.5× faster on 30,000 residuals, where the QR of the
    tall matrix is most of a step. Normal equations square the condition number, which float64 absorbs; the
    refinement that follows solves normal equations too. In float32, and for the other names, it is
    `make_solver`'s.

    Arguments:
        solver: a name from `SOLVERS`.
        rtol, atol: the coarse stage's tolerances.

    Returns:
        The solver object.
    """
    if solver == "lm" and _working_float().bits == 64:
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    return make_solver(solver, rtol, atol)


def working_tolerances(rtol: float, atol: float) -> tuple[float, float]:
    """The tolerances raised to what the working precision can meet.

    Arguments:
        rtol, atol: the requested relative and absolute tolerances.

    Returns:
        ``(max(rtol, RTOL_FLOOR_EPS·eps), max(atol, ATOL_FLOOR_EPS·eps))`` with eps the machine epsilon of JAX's
        default float type (float64 when brdffit is imported, float32 inside ``jax.enable_x64(False)``).
    """
    eps = float(_working_float().eps)
    return max(rtol, RTOL_FLOOR_EPS * eps), max(atol, ATOL_FLOOR_EPS * eps)


def solver_name(solver) -> str:
    """A readable name of a solver object: its table name when it came from the table, else its class name."""
    for name, (constructor, _) in SOLVERS.items():
        if type(solver) is constructor:
            return name
    return type(solver).__name__
