"""The nonlinear solve: the one table from solver names (CLI, `fit(solver="lm")`) to solver objects (the engine's
own Levenberg-Marquardt, `brdffit.fitting.marquardt`, and optimistix's solvers), the one interface the pipeline
solves through (`BatchSolver`, `batch_solver`), and the compiled, batched optimistix solve of a problem's outer
parameters."""

from __future__ import annotations

import dataclasses
import importlib
import time
from typing import TYPE_CHECKING, Protocol

from .._lazy import module

# The table is read by the CLI's help, which must not load JAX or optimistix; they are imported when
# a solver is made or a solve compiled.
jax = module("jax")
jnp = module("jax.numpy")
lx = module("lineax")
optx = module("optimistix")
problem_module = module("brdffit.fitting.problem")
separable = module("brdffit.fitting.separable")
model_module = module("brdffit.models.model")

arrays = module("brdffit.arrays")
programs = module("brdffit.programs")
outcome = module("brdffit.fitting.outcome")
np = module("numpy")

if TYPE_CHECKING:
    from .problem import FitData, Problem

__all__ = ["SOLVERS", "BatchSolver", "OptimistixStarts", "batch_solver", "make_solver", "coarse_solver",
           "solver_name", "working_tolerances", "compiled_solve", "outer_params", "no_pins"]

# Floors of the convergence tolerances in units of the working precision's machine epsilon: rounding makes
# successive float32 steps differ by a few ulps of the cost and of the parameters, so a float32 fit (run under
# `jax.enable_x64(False)`) with the float64 defaults would never meet them and end at max_steps. In float64 the
# floors (2.2e-14 and 2.2e-16) lie below the defaults and change nothing.
RTOL_FLOOR_EPS = 100.0
ATOL_FLOOR_EPS = 1.0

# name -> (constructor, description). Every constructor takes rtol and atol. The solver moves the outer
# parameters only (`Problem.outer`); the linear amplitudes are projected out (`brdffit.fitting.separable`).
SOLVERS = {
    "lm": ("brdffit.fitting.marquardt:Marquardt",
           "Levenberg-Marquardt on the separable normal equations, stepped on the host over one compiled pass per "
           "model (default; brdffit.fitting.marquardt)"),
    "optx-lm": ("optimistix:LevenbergMarquardt", "optimistix's Levenberg-Marquardt, the whole solve compiled"),
    "gauss-newton": ("optimistix:GaussNewton", "Gauss-Newton, undamped; fast near the optimum, fragile far from it"),
    "dogleg": ("optimistix:Dogleg", "Powell's dogleg trust-region method"),
    "indirect-lm": ("optimistix:IndirectLevenbergMarquardt",
                    "Levenberg-Marquardt with an iterative damping search"),
    "bfgs": ("optimistix:BFGS", "BFGS quasi-Newton minimiser of the summed squares"),
}


def constructor(name: str):
    """The class behind a `SOLVERS` name (imported on first use)."""
    where, _, attribute = SOLVERS[name][0].partition(":")
    return getattr(importlib.import_module(where), attribute)


def make_solver(solver, rtol: float, atol: float):
    """Turn a solver name into a solver object; pass a solver object through unchanged.

    Arguments:
        solver: a name from `SOLVERS`, a `Marquardt`, or any `optimistix.AbstractLeastSquaresSolver` /
            `AbstractMinimiser`.
        rtol, atol: tolerances for a named solver.

    Returns:
        The solver object.

    Raises:
        ValueError: for an unknown name.
    """
    if isinstance(solver, str):
        try:
            make = constructor(solver)
        except KeyError:
            raise ValueError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)} or pass an "
                             "optimistix solver object") from None
        return make(rtol=rtol, atol=atol)
    # Marquardt first: `or` leaves optimistix unimported (0.2 s) for brdffit's own solver.
    if isinstance(solver, constructor("lm")) or isinstance(solver, (optx.AbstractLeastSquaresSolver,
                                                                     optx.AbstractMinimiser)):
        return solver
    raise ValueError(f"solver must be a name ({', '.join(SOLVERS)}) or an optimistix least-squares solver or "
                     f"minimiser, got {type(solver).__name__}")


def _working_float():
    """`jnp.finfo` of JAX's default float type: float64 once brdffit is imported, float32 inside
    ``jax.enable_x64(False)``."""
    return jnp.finfo(jnp.result_type(float))


# The relative offset at which the default solver's coarse stage stops (Bates & Watts 1981; `Marquardt.offset`,
# 1e-3 for a fit's answer): the remaining Gauss-Newton step is then about 3e-2 √p standard errors long and the cost
# within ~1e-3 p of its minimum in χ² units (the offset squared times p), far inside the subsample's own error of
# ~√(n/n_s) standard errors that the refinement removes, and inside what a selection's screen ranks on (AIC's price
# of 2 a parameter, a held-out margin of 5 %). Misspecified fits approach their optimum linearly, with alternating
# steps: at 1e-2 the screen of a real paper's selection took 12 % longer, of a felt 20 %, for the same choices.
COARSE_OFFSET = 3e-2


def coarse_solver(solver, rtol: float, atol: float):
    """The solver of a two-stage fit's coarse stage (`brdffit.fitting.api.COARSE_SAMPLES` samples) and of a
    selection's screen (`brdffit.select`) for a named solver.

    For ``"optx-lm"`` in float64 it is optimistix's Levenberg-Marquardt whose damped step solves the normal equations
    (JᵀJ + λI) δ = −Jᵀr by Cholesky (lineax's ``Normal(Cholesky())``) instead of a QR factorisation of the
    stacked [J; √λ I] (optimistix's default): the same steps, faster on many residuals, where the QR of the
    tall matrix is most of a step. Normal equations square the condition number, which float64 absorbs; the
    refinement that follows solves normal equations too. For ``"lm"`` it is the engine's `Marquardt` stopping at
    the relative offset `COARSE_OFFSET`. In float32, and for the other names, it is `make_solver`'s.

    Arguments:
        solver: a name from `SOLVERS`.
        rtol, atol: the coarse stage's tolerances.

    Returns:
        The solver object.
    """
    if solver == "optx-lm" and _working_float().bits == 64:
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    if solver == "lm":
        return constructor("lm")(rtol=rtol, atol=atol, offset=COARSE_OFFSET)
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
    for name in SOLVERS:
        if type(solver) is constructor(name):
            return name
    return type(solver).__name__


def outer_params(problem: Problem, y: dict, data: FitData, pins: dict | None = None) -> dict:
    """Physical values of every parameter from the solver's unconstrained ``y``, the fixed values and, for the
    projected amplitudes, zeros (placeholders that the projection replaces).

    Arguments:
        problem: the `Problem`.
        y: outer name -> unconstrained value.
        data: the `FitData` (its ``fixed`` values).
        pins: outer name -> ``(mask, value)``: where the mask is set, the physical value is held at ``value``
            whatever ``y`` is (its derivative is 0). The pipeline holds parameters this way without compiling
            another program.
    """
    placeholders = {a: jnp.zeros(problem.channels) for a in problem.linear}
    params = problem_module.physical_params(problem, y, dict(placeholders, **data.fixed))
    for name, (mask, value) in (pins or {}).items():
        params[name] = jnp.where(mask, value, params[name])
    return params


def no_pins(problem: Problem, y0: dict) -> dict:
    """Pins that hold nothing, shaped like ``y0`` (see `outer_params`)."""
    return {name: (jnp.zeros(jnp.shape(v), bool), jnp.zeros(jnp.shape(v))) for name, v in y0.items()}


def _solve_one(y0: dict, data: FitData, pins: dict, problem: Problem):
    def to_params(y, data):
        return outer_params(problem, y, data, pins)

    def fn(y, args):
        if problem.linear:
            return separable.projected_residuals(problem, to_params, y, data)
        return problem_module.residuals_of(problem, model_module.evaluate_pair(problem.model(to_params(y, data)),
                                                                               data.pair), data)

    sol = optx.least_squares(fn, problem.solver, y0, max_steps=problem.max_steps, throw=False)
    params, f = separable.project(problem, to_params(sol.value, data), data)
    r = problem_module.residuals_of(problem, f, data)
    cost = jnp.sum(r * r)
    return {
        "params": params,
        "cost": cost,
        "steps": sol.stats["num_steps"],
        "max_steps": sol.result == optx.RESULTS.nonlinear_max_steps_reached,
        "nonfinite": (sol.result == optx.RESULTS.nonfinite) | ~jnp.isfinite(cost),
    }


_COMPILED: dict = {}


def _signature(tree) -> tuple:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return treedef, tuple((leaf.shape, str(leaf.dtype)) for leaf in leaves)


def compiled_solve(problem: Problem, y0: dict, data: FitData):
    """The compiled solve for this problem and these shapes, batched over materials and starts, and the seconds
    spent compiling it.

    ``y0`` and the pins (`outer_params`) have two leading axes (material, start) on every leaf and ``data`` one
    (material): the solve is vmapped over both. Executables are cached in this process, keyed by the problem and
    the shapes, so a second fit of the same model and shapes compiles nothing (compile time 0).

    Arguments:
        problem: the `Problem`.
        y0: outer name -> unconstrained starting values ``(materials, starts) + shape``.
        data: the `FitData` with a leading material axis.

    Returns:
        ``(executable, compile_seconds)``; ``executable(y0, data, pins)`` gives a dict of ``params`` (physical, every
        parameter, amplitudes solved), ``cost``, ``steps``, ``max_steps`` and ``nonfinite``, each with the two
        leading axes.
    """
    key = (problem, _signature(y0), _signature(data))
    if key in _COMPILED:
        return _COMPILED[key], 0.0
    start = time.perf_counter()
    per_material = jax.vmap(lambda y, d, p: _solve_one(y, d, p, problem), in_axes=(0, None, 0))
    batched = jax.vmap(per_material, in_axes=(0, 0, 0))
    lowered = jax.jit(batched).lower(y0, data, no_pins(problem, y0))
    executable = lowered.compile(compiler_options=programs.compiler_options())
    _COMPILED[key] = executable
    return executable, time.perf_counter() - start


class BatchSolver(Protocol):
    """What the pipeline solves through (`brdffit.fitting.api._polish`): every start of every material of a batch,
    each start's outcome a `brdffit.fitting.outcome.SolveOutcome`. The engine's `Marquardt` implements it, and
    `OptimistixStarts` for any optimistix solver."""

    def solve_starts(self, problem: Problem, starts: list, data: FitData, *, held=None, metrics: bool = False,
                     max_steps: int | None = None) -> tuple:
        """Solve the starts.

        Arguments:
            problem: the `Problem`; its outer parameters are solved, its amplitudes projected where it says so.
            starts: for each material, its starts (physical values of every parameter).
            data: `FitData` with a leading material axis, the fixed values of every material in ``fixed``.
            held: for each material, outer name -> physical value to hold (NaN: free), the same for its starts.
            metrics: ``data`` is the whole data: give the answers' metric sums too (where the solver can).
            max_steps: a step limit below the problem's (where the solver can; the compiled programs stay).

        Returns:
            ``(outcomes, compile_seconds, run_seconds)``: for each material one `SolveOutcome` a start.
        """


@dataclasses.dataclass(frozen=True)
class OptimistixStarts:
    """An optimistix solver as a `BatchSolver`: one compiled solve (`compiled_solve`) of every start of every
    material in unconstrained coordinates; held parameters are pinned inside it. ``metrics`` and ``max_steps``
    are not used (its outcomes carry no normal equations; its step limit is the problem's, compiled in)."""

    solver: object

    def solve_starts(self, problem: Problem, starts: list, data: FitData, *, held=None, metrics: bool = False,
                     max_steps: int | None = None) -> tuple:
        specs = problem.specs
        y0 = {name: arrays.to_device(np.stack([np.stack([np.asarray(specs[name].to_unconstrained(s[name]))
                                                         for s in material]) for material in starts]))
              for name in problem.outer}
        executable, compile_time = compiled_solve(problem, y0, data)
        pins = no_pins(problem, y0)
        if held:
            for name in problem.outer:
                value = np.stack([np.broadcast_to(np.asarray(h.get(name, np.nan), dtype=float),
                                                  np.shape(y0[name])[1:]) for h in held])
                pins[name] = (arrays.to_device(np.isfinite(value)), arrays.to_device(np.nan_to_num(value)))
        t0 = time.perf_counter()
        out = jax.tree_util.tree_map(np.asarray, jax.block_until_ready(executable(y0, data, pins)))
        run_time = time.perf_counter() - t0
        outcomes = [[outcome.SolveOutcome({k: v[m, i] for k, v in out["params"].items()}, float(out["cost"][m, i]),
                                          steps=int(out["steps"][m, i]), max_steps=bool(out["max_steps"][m, i]),
                                          nonfinite=bool(out["nonfinite"][m, i])) for i in range(len(material))]
                    for m, material in enumerate(starts)]
        return outcomes, compile_time, run_time


def batch_solver(solver) -> BatchSolver:
    """The `BatchSolver` of a problem's solver: the engine's `Marquardt` is one; an optimistix solver is wrapped
    in `OptimistixStarts`."""
    return solver if hasattr(solver, "solve_starts") else OptimistixStarts(solver)
