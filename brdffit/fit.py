"""Least-squares fitting of a model to measurements with optimistix (docs/fitting.md).

`fit` fits one data set (all starts of a multistart in one vmapped solve); `fit_many` fits equally shaped data
sets in one vmapped, jitted solve. Bounds are enforced by the transforms of `brdffit.params`; the Laplace
covariance comes from the Gauss-Newton approximation JᵀJ of the residual Jacobian in physical units.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import time

import jax
import jax.numpy as jnp
import numpy as np

from .fit_result import FitResult, param_labels
from .initial_guess import MAX_INIT_SAMPLES, initial_guesses
from .losses import LOSSES, ROBUST, loss_epsilon
from .metrics import fit_metrics
from .models.model import Model, global_names
from .models.registry import get as get_model
from .normal_equations import accumulate, chunks
from .params import at_bound
from .problem import (FitData, Problem, compiled_solve, make_fit_data, physical_params, residual_fn,
                      stack_data)
from .progress import Progress
from .refine import refine
from .solvers import coarse_solver, make_solver, solver_name, working_tolerances

__all__ = ["fit", "fit_many", "FitError", "CHANNEL_MODES"]

CHANNEL_MODES = ("shared-shape", "independent")
# Data with more (sample, channel) values than this is first solved on a subsample of COARSE_SAMPLES samples and
# then refined on all of it (`brdffit.refine`).
COARSE_RESIDUALS = 150_000
COARSE_SAMPLES = 10_000
COARSE_RTOL, COARSE_ATOL = 1e-5, 1e-8
_CORRELATION_WARNING = 0.99
# A fit whose final point still leaves a predicted Gauss-Newton decrease above this fraction of the cost is
# "stalled", not converged (`_predicted_decrease`). Converged LM fits leave ~1e-12; the stalls the stability
# study found (docs/stability.md) leave more than the cost itself.
STALL_TOLERANCE = 1e-4


class FitError(RuntimeError):
    """Raised by a strict fit that did not converge; ``.result`` holds the `FitResult`."""

    def __init__(self, message: str, result: FitResult):
        super().__init__(message)
        self.result = result


def _parse_robust(robust):
    if robust is None or isinstance(robust, str):
        kind, scale = robust, None
    else:
        kind, scale = robust
    if kind not in ROBUST:
        raise ValueError(f"robust must be None, 'huber', 'cauchy' or a (kind, scale) pair, got {robust!r}")
    if scale is not None and not scale > 0:
        raise ValueError(f"the robust scale must be positive, got {scale!r}")
    return kind, scale


def _resolve_model(model, channels: int) -> Model:
    if isinstance(model, Model):
        if model.channels != channels:
            raise ValueError(f"the model has {model.channels} channels but the measurements have {channels}")
        return model
    return get_model(model, channels=channels)


def _split_fixed(model: Model, fixed, free) -> dict:
    """name -> value of every parameter held fixed: declared-fixed ones unless freed, plus the user's."""
    specs = model.param_specs
    free = set(free or ())
    for name in free:
        specs[name]  # raises KeyError naming the valid parameters
    values = {s.name: model.params[s.name] for s in specs if s.fixed and s.name not in free}
    if isinstance(fixed, dict):
        for name, value in fixed.items():
            values[name] = model.replace(**{name: value}).params[name]
    else:
        for name in fixed or ():
            values[name] = model.params[specs[name].name]
    return values


def _subsample(measurements, limit: int, seed: int):
    if measurements.n <= limit:
        return measurements
    return measurements.subsample(limit, seed=seed)


def _unconstrained(problem: Problem, starts: list[dict]) -> dict:
    specs = problem.specs
    return {name: jnp.stack([jnp.asarray(specs[name].to_unconstrained(s[name]), dtype=float) for s in starts])
            for name in problem.free}


def _physical_normal_matrices(problem: Problem, params: dict, data: FitData):
    """JᵀJ, Jᵀ diag(r²) J and Jᵀr with J the residual Jacobian w.r.t. the free physical parameters (chunked)."""
    data = data._replace(fixed={k: v for k, v in params.items() if k not in problem.free})
    sums = accumulate(problem, {k: params[k] for k in problem.free}, chunks(data), physical=True)
    return sums.jtj, sums.meat, sums.jtr


def _predicted_decrease(problem: Problem, params: dict, jtj, jtr) -> float:
    """The decrease of Σr² that a Gauss-Newton step from ``params`` predicts, moving only the way the bounds
    allow: rᵀJ (JᵀJ)⁺ Jᵀr over the free scalars, leaving out those at a bound whose descent direction −Jᵀr
    points out of the box (Karush-Kuhn-Tucker: there the bound is active). Near 0 at a true (constrained)
    optimum; a solver that stalled (undamped Gauss-Newton thrown far away, or a transform saturated at a bound
    that the data do not want) leaves a large value."""
    specs = problem.specs
    values, lower, upper, near = [], [], [], []
    for name in problem.free:
        spec = specs[name]
        value = np.ravel(np.asarray(params[name], dtype=float))
        values.append(value)
        lower.append(np.full(value.shape, spec.lower))
        upper.append(np.full(value.shape, spec.upper))
        near.append(np.ravel(at_bound(value, spec)))
    values, lower, upper, near = (np.concatenate(a) for a in (values, lower, upper, near))
    at_lower = near & (np.abs(values - lower) <= np.abs(values - upper))
    at_upper = near & ~at_lower
    g = np.asarray(jtr, dtype=float)
    moving = ~((at_lower & (g > 0)) | (at_upper & (g < 0)))
    if not moving.any():
        return 0.0
    h = np.asarray(jtj, dtype=float)[np.ix_(moving, moving)]
    g = g[moving]
    scale = np.sqrt(np.maximum(np.diag(h), 1e-300))  # Jacobi scaling: physical units span many decades
    step = np.linalg.lstsq(h / np.outer(scale, scale), g / scale, rcond=1e-12)[0]
    return float(max((g / scale) @ step, 0.0))


def _to_physical(problem: Problem, y: dict, matrices):
    """Map normal matrices in the unconstrained variables u to the physical ones p: J_p = J_u diag(du/dp)."""
    specs = problem.specs
    derivative = np.concatenate([np.ravel(np.asarray(jax.jvp(specs[name].from_unconstrained, (jnp.asarray(y[name]),),
                                                             (jnp.ones_like(jnp.asarray(y[name])),))[1]))
                                 for name in problem.free])
    scale = 1.0 / np.outer(derivative, derivative)
    return tuple(np.asarray(m, dtype=float) * scale for m in matrices)


def _laplace(jtj, meat, rss: float, loss: str, n_valid: int):
    """Gauss-Newton covariance s² (JᵀJ)⁻¹ of the free parameters, with s² = Σr²/dof (1 for ``loss="sigma"``),
    and the sandwich covariance that stays valid when the residuals' variance differs between samples.

    Directions of JᵀJ with eigenvalues below 1e-12 of the largest are undetermined by the data: parameters with
    a component along them get infinite variance.
    """
    p = jtj.shape[0]
    dof = max(n_valid - p, 1)
    variance = 1.0 if loss == "sigma" else rss / dof
    eigval, eigvec = np.linalg.eigh(jtj)
    good = eigval > 1e-12 * max(eigval.max(initial=0.0), 1e-300)
    inv = (eigvec[:, good] / eigval[good]) @ eigvec[:, good].T
    cov = variance * inv
    # Heteroscedasticity-consistent "sandwich" covariance (White 1980, HC0): (JᵀJ)⁻¹ Jᵀ diag(r²) J (JᵀJ)⁻¹.
    sandwich = inv @ meat @ inv
    undetermined = np.any(np.abs(eigvec[:, ~good]) > 1e-6, axis=1) if (~good).any() else np.zeros(p, bool)
    for matrix in (cov, sandwich):
        matrix[undetermined, :] = np.inf
        matrix[:, undetermined] = np.inf
    return cov, sandwich, variance, undetermined


def _per_param(params: dict, free, flat_std) -> dict:
    """Split a flat vector over the free parameters (model order) into name -> array; 0 for fixed ones."""
    out, offset = {}, 0
    for name in params:
        size = np.asarray(params[name]).size
        if name in free:
            out[name] = flat_std[offset:offset + size].reshape(np.shape(params[name]))
            offset += size
        else:
            out[name] = np.zeros(np.shape(params[name]))
    return out


@functools.lru_cache(maxsize=32)
def _channel_cost(problem: Problem):
    """Jitted Σr² per channel."""
    return jax.jit(lambda params, data: jnp.sum(residual_fn(problem, params, data) ** 2, axis=0))


def _information_criteria(loss: str, cost: float, n: int, k: int) -> tuple[float, float]:
    """AIC and BIC of a least-squares fit (docs/fitting.md): from χ² with known σ, else from the profile
    Gaussian likelihood n ln(RSS/n)."""
    if loss == "sigma":
        base = cost
    else:
        base = n * np.log(max(cost, 1e-300) / max(n, 1))
    return float(base + 2 * k), float(base + k * np.log(max(n, 1)))


def _status(problem: Problem, outcome: dict, params: dict) -> tuple[str, list]:
    specs = problem.specs
    hit = []
    for name in problem.free:
        flags = np.atleast_1d(at_bound(params[name], specs[name]))
        labels = param_labels(params, [name])
        hit.extend(label for label, flag in zip(labels, flags) if flag)
    if bool(outcome["nonfinite"]):
        return "nonfinite", hit
    if bool(outcome["max_steps"]):
        return "max-steps", hit
    return ("converged-at-bound" if hit else "converged"), hit


def _start_status(outcome: dict) -> str:
    if bool(outcome["nonfinite"]):
        return "nonfinite"
    return "max-steps" if bool(outcome["max_steps"]) else "converged"


def _json_params(params: dict) -> dict:
    return {k: np.asarray(v, dtype=float).tolist() for k, v in params.items()}


def _canonical(problem: Problem, y: dict, fixed: dict, outcome: dict):
    """Put the solution in each lobe's canonical order (`Lobe.canonical`, e.g. Lafortune lobes sorted by n).

    Returns the (possibly reordered) unconstrained values and the outcome, without the refinement's normal
    matrices when the order changed (they belong to the old order).
    """
    params = physical_params(problem, y, fixed)
    ordered = dict(params)
    for lobe, names in zip(problem.lobes, global_names(problem.lobes)):
        local = {spec.name: params[name] for spec, name in zip(lobe.param_specs(), names)}
        canon = lobe.canonical(local)
        ordered.update({name: canon[spec.name] for spec, name in zip(lobe.param_specs(), names)})
    if all(np.array_equal(np.asarray(ordered[k]), np.asarray(params[k])) for k in params):
        return y, outcome
    specs = problem.specs
    y = {k: specs[k].to_unconstrained(ordered[k]) for k in problem.free}
    return y, {k: v for k, v in outcome.items() if k != "normal_matrices"}


def _coarse_problem(problem: Problem, solver) -> Problem:
    """The coarse stage's problem: a named solver gets the looser `COARSE_RTOL` (and, for "lm", normal
    equations: `brdffit.solvers.coarse_solver`); its answer only has to land within the subsample's statistical
    error of the optimum (about 1/√COARSE_SAMPLES), which the refinement then removes. A solver object is used as
    given."""
    if not isinstance(solver, str):
        return problem
    loose = coarse_solver(solver, max(COARSE_RTOL, problem.solver.rtol), max(COARSE_ATOL, problem.solver.atol))
    return dataclasses.replace(problem, solver=loose)


def _use_coarse(coarse, measurements) -> bool:
    if coarse not in ("auto", True, False):
        raise ValueError(f"coarse must be 'auto', True or False, got {coarse!r}")
    if coarse == "auto":
        return measurements.n * measurements.n_channels > COARSE_RESIDUALS and measurements.n > COARSE_SAMPLES
    return bool(coarse) and measurements.n > COARSE_SAMPLES


def _uncertainty(problem: Problem, y: dict, params: dict, data: FitData, outcome: dict, hit: list, n_valid: int):
    """Laplace and sandwich standard errors, covariance, correlation, noise variance, undetermined flags, and
    the cost decrease a further Gauss-Newton step predicts (None after a full-data refinement, whose own
    termination is that test)."""
    decrease = None
    if problem.free:
        if "normal_matrices" in outcome and not hit:
            matrices = _to_physical(problem, y, outcome["normal_matrices"])
        else:  # near a bound du/dp is ill-conditioned: linearise in the physical parameters directly
            jtj, meat, jtr = _physical_normal_matrices(problem, params, data)
            matrices = (jtj, meat)
            decrease = _predicted_decrease(problem, params, jtj, jtr)
        cov, sandwich, variance, undetermined = _laplace(*matrices, float(outcome["cost"]), problem.loss, n_valid)
    else:
        cov, sandwich = np.zeros((0, 0)), np.zeros((0, 0))
        variance, undetermined = float("nan"), np.zeros(0, bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        std = np.sqrt(np.diag(cov))
        std_sandwich = np.sqrt(np.diag(sandwich))
        correlation = cov / np.outer(std, std)
    return cov, correlation, std, std_sandwich, variance, undetermined, decrease


def _fit_warnings(problem: Problem, labels: list, std, std_sandwich, correlation, undetermined, hit: list) -> list:
    """The human-readable warnings of a fit: non-uniform noise, undetermined or correlated parameters, bounds."""
    warnings = []
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = std_sandwich / std
    if np.any(np.isfinite(ratio) & ((ratio > 2.0) | (ratio < 0.5))):
        warnings.append("Laplace and sandwich standard errors differ by more than 2x: the residuals' variance "
                        "is not uniform (use loss='sigma' with known sigma, or read stderr_robust)")
    if undetermined.any():
        names = [label for label, u in zip(labels, undetermined) if u]
        warnings.append(f"JᵀJ is singular: {', '.join(names)} not determined by these data (stderr = inf)")
    for a, b in itertools.combinations(range(len(labels)), 2):
        rho = correlation[a, b]
        if np.isfinite(rho) and abs(rho) > _CORRELATION_WARNING:
            warnings.append(f"{labels[a]} and {labels[b]} are correlated (ρ = {rho:+.4f}): not separately "
                            "identifiable from these data")
    if hit:
        warnings.append(f"parameters at a bound: {', '.join(hit)}")
    specs = problem.specs
    for name in problem.free:
        spec = specs[name]
        if spec.colour and spec.scale and spec.lower == 0 and all(f"{name}[{c}]" in hit
                                                                    for c in range(problem.channels)):
            warnings.append(f"{name} went to 0 in every channel: its lobe contributes nothing, a model without "
                            "it suffices")
    return warnings


def _finish(problem: Problem, model: Model, measurements, data: FitData, y: dict, outcome: dict, *, starts: list,
            times: dict, strategy: str = "full") -> FitResult:
    """Build the `FitResult` of the kept solution ``y`` (one material, one start)."""
    params = {k: np.asarray(v) for k, v in physical_params(problem, y, data.fixed).items()}
    fitted = model.replace(**params)
    valid = np.isfinite(measurements.values)
    n_valid = int(valid.sum())
    labels = param_labels(params, problem.free)
    status, hit = _status(problem, outcome, params)
    cov, correlation, std, std_sandwich, variance, undetermined, decrease = _uncertainty(
        problem, y, fitted.params, data, outcome, hit, n_valid)
    cost = float(outcome["cost"])
    if status.startswith("converged") and decrease is not None and decrease > STALL_TOLERANCE * cost:
        status = "stalled"
    warnings = _fit_warnings(problem, labels, std, std_sandwich, correlation, undetermined, hit)
    if status == "stalled":
        warnings.append(f"the solver stopped where a Gauss-Newton step still predicts a cost decrease of "
                        f"{decrease:.3g} ({decrease / max(cost, 1e-300):.2g} of the cost): not a minimum "
                        "(try solver='lm', init='auto' or multistart)")
    k = len(labels)
    aic, bic = _information_criteria(problem.loss, cost, n_valid, k)
    per_channel_cost = outcome.get("channel_cost")  # a refinement's last pass has it
    if per_channel_cost is None:
        per_channel_cost = np.asarray(_channel_cost(problem)(fitted.params, data))
    counts = np.maximum(valid.sum(axis=0), 1)
    metrics = {"rmse_loss": np.sqrt(per_channel_cost / counts)}
    metrics.update(fit_metrics(fitted, measurements, pair=data.pair))
    return FitResult(
        model=fitted, params=dict(fitted.params), stderr=_per_param(params, problem.free, std),
        stderr_robust=_per_param(params, problem.free, std_sandwich), covariance=cov, correlation=correlation,
        labels=labels, metrics=metrics, n_samples=n_valid, n_params=k, dof=n_valid - k, cost=cost, aic=aic,
        bic=bic, status=status, bounds_hit=hit, warnings=warnings, steps=int(outcome["steps"]),
        compile_time=times["compile"], run_time=times["run"], init_time=times["init"], loss=problem.loss,
        solver=solver_name(problem.solver), channel_mode="shared-shape", fixed=sorted(data.fixed), starts=starts,
        noise_variance=float(variance), strategy=strategy, models=[fitted],
    )


def _prepare(measurements, model, *, loss, solver, fixed, free, robust, max_steps, rtol, atol):
    """Validate the arguments and build the `Problem`, the base model and the fixed values."""
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    if loss == "sigma" and measurements.sigma is None:
        raise ValueError("loss='sigma' needs measurements with per-sample sigma; these have none")
    robust_kind, robust_scale = _parse_robust(robust)
    model = _resolve_model(model, measurements.n_channels)
    fixed_values = _split_fixed(model, fixed, free)
    problem = Problem(
        lobes=model.lobes, channels=model.channels,
        free=tuple(s.name for s in model.param_specs if s.name not in fixed_values),
        loss=loss, robust=robust_kind, solver=make_solver(solver, rtol, atol), max_steps=int(max_steps),
    )
    return problem, model, fixed_values, robust_scale


def _starting_points(problem: Problem, model: Model, measurements, fixed_values: dict, init, multistart: int,
                     seed: int, robust_scale):
    """The starts (physical dicts) and the robust scale, from a subsample of the data."""
    eps = loss_epsilon(problem.loss, measurements.values)
    sub = make_fit_data(_subsample(measurements, MAX_INIT_SAMPLES, seed), fixed_values, eps, 1.0)
    base = dict(model.params, **fixed_values)
    plain = Problem(problem.lobes, problem.channels, problem.free, problem.loss, None, problem.solver,
                    problem.max_steps)

    def extra_starts():  # the multistart starts that follow a given first start
        return initial_guesses(plain, base, sub, multistart, seed)[1:] if multistart else []

    if isinstance(init, str) and init == "auto":
        starts = initial_guesses(plain, base, sub, multistart, seed)
    elif isinstance(init, str) and init == "model":
        starts = [base] + extra_starts()
    elif isinstance(init, list):
        starts = initial_guesses(plain, base, sub, multistart, seed, candidates=init)
    elif isinstance(init, (dict, Model)):
        given = init.params if isinstance(init, Model) else model.replace(**init).params
        starts = [dict(base, **{k: v for k, v in given.items() if k not in fixed_values})] + extra_starts()
    else:
        raise ValueError(f"init must be 'auto', 'model', a Model, a dict of values or a list of candidate "
                         f"shape settings, got {init!r}")
    if problem.robust is not None and robust_scale is None:
        r = np.asarray(residual_fn(plain, {k: jnp.asarray(v) for k, v in starts[0].items()}, sub))
        mask = np.asarray(sub.mask)
        robust_scale = float(max(1.4826 * np.median(np.abs(r[mask])), 1e-12)) if mask.any() else 1.0
    return starts, eps, robust_scale if robust_scale is not None else 1.0


def fit(measurements, model, *, loss: str = "cosine", solver="lm", init="auto", fixed=None, free=None,
        multistart: int = 0, channel_mode: str = "shared-shape", robust=None, max_steps: int = 256,
        rtol: float = 1e-8, atol: float = 1e-12, seed: int = 0, coarse="auto",
        strict: bool = False, progress: bool = False) -> FitResult:
    """Fit a model to measurements by nonlinear least squares.

    Arguments:
        measurements: `brdffit.Measurements`.
        model: a spec string (``"lambert+ggx"``) or a `Model` (its values are the start when ``init="model"``).
        loss: ``"cosine"`` (default), ``"log"``, ``"relative"``, ``"absolute"`` or ``"sigma"`` (docs/fitting.md).
        solver: a name from `brdffit.solvers.SOLVERS` (``"lm"``, ``"gauss-newton"``, ``"dogleg"``,
            ``"indirect-lm"``, ``"bfgs"``) or any optimistix least-squares solver or minimiser.
        init: ``"auto"`` (data-driven guess, `brdffit.initial_guess`), ``"model"`` (the model's values), a
            `Model`, a dict of starting values, or a list of candidate shape-parameter settings (dicts) that the
            initial guess scores, with their amplitudes solved, instead of its own grid.
        fixed: parameters held fixed: a dict name -> value, or names held at the model's values.
        free: names of parameters declared fixed by default (e.g. the toon ``width``) that this fit frees.
        multistart: extra quasi-random starts over the bounds; all run in one vmapped solve, the lowest cost is
            kept and every start is recorded in ``result.starts``.
        channel_mode: ``"shared-shape"`` (colour parameters per channel, shape parameters shared and fitted
            jointly) or ``"independent"`` (one fit per channel).
        robust: None, ``"huber"``, ``"cauchy"`` or ``(kind, scale)``; without a scale it is 1.4826 times the
            median absolute residual of the initial guess.
        max_steps: the solver's step limit.
        rtol, atol: the solver's convergence tolerances (optimistix's Cauchy termination), raised to what the
            working precision can meet (`brdffit.solvers.working_tolerances`; changes nothing in float64).
        seed: seed of the subsample and of the quasi-random starts.
        coarse: ``"auto"`` solves data with more than `COARSE_RESIDUALS` values on a seeded subsample of
            `COARSE_SAMPLES` samples first and then refines on all of it (`brdffit.refine`); True forces and
            False disables this. The answer is the full-data optimum either way; only the time differs.
        strict: raise `FitError` instead of returning a non-converged result.
        progress: report the stages (initial guess, the batched solve of all starts, refinement, uncertainty) on
            a progress line on stderr (`brdffit.progress.Progress`).

    Returns:
        A `FitResult`.
    """
    if channel_mode not in CHANNEL_MODES:
        raise ValueError(f"channel_mode must be one of {', '.join(CHANNEL_MODES)}, got {channel_mode!r}")
    rtol, atol = working_tolerances(rtol, atol)
    kwargs = dict(loss=loss, solver=solver, init=init, fixed=fixed, free=free, multistart=multistart,
                  robust=robust, max_steps=max_steps, rtol=rtol, atol=atol, seed=seed, coarse=coarse,
                  strict=strict)
    if channel_mode == "independent":
        return _fit_independent(measurements, model, **kwargs)
    problem, model, fixed_values, robust_scale = _prepare(
        measurements, model, loss=loss, solver=solver, fixed=fixed, free=free, robust=robust,
        max_steps=max_steps, rtol=rtol, atol=atol)
    bar = Progress(f"fit {model.spec}", 4, enabled=progress, unit="stages")
    bar.update(0, "initial guess")
    t0 = time.perf_counter()
    starts, eps, robust_scale = _starting_points(problem, model, measurements, fixed_values, init, multistart,
                                                 seed, robust_scale)
    init_time = time.perf_counter() - t0
    data = make_fit_data(measurements, fixed_values, eps, robust_scale)
    y0 = _unconstrained(problem, starts)
    two_stage = bool(problem.free) and _use_coarse(coarse, measurements)
    strategy = f"coarse ({COARSE_SAMPLES} samples) + refine" if two_stage else "full"
    bar.update(1, f"solving {len(starts)} start{'s' if len(starts) > 1 else ''} in one batch"
                  f"{f' on {COARSE_SAMPLES} samples' if two_stage else ''}")
    if problem.free:
        solve_data, solve_problem = data, problem
        if two_stage:
            solve_data = make_fit_data(measurements.subsample(COARSE_SAMPLES, seed=seed), fixed_values, eps,
                                       robust_scale)
            solve_problem = _coarse_problem(problem, solver)
        executable, compile_time = compiled_solve(solve_problem, y0, solve_data, data_batched=False)
        t0 = time.perf_counter()
        out = jax.block_until_ready(executable(y0, solve_data))
        run_time = time.perf_counter() - t0
    else:
        compile_time = run_time = 0.0
        r = residual_fn(problem, dict(fixed_values), data)
        out = {"y": {}, "cost": jnp.sum(r * r)[None], "steps": jnp.zeros(1, int),
               "successful": jnp.ones(1, bool), "max_steps": jnp.zeros(1, bool), "nonfinite": jnp.zeros(1, bool)}
    out = jax.tree_util.tree_map(np.asarray, out)
    costs = np.where(out["nonfinite"], np.inf, out["cost"])
    best = int(np.argmin(costs)) if np.isfinite(costs).any() else 0
    records = [{"init": _json_params(s), "cost": float(out["cost"][i]), "status": _start_status(
        {k: v[i] for k, v in out.items() if k != "y"}), "steps": int(out["steps"][i])} for i, s in enumerate(starts)]
    y = {k: v[best] for k, v in out["y"].items()}
    outcome = {k: v[best] for k, v in out.items() if k != "y"}
    if two_stage:
        bar.update(2, f"refining on all {measurements.n} samples")
        t0 = time.perf_counter()
        coarse_steps = int(outcome["steps"])
        y, outcome = refine(problem, y, data, rtol=rtol, atol=atol)
        outcome["steps"] = coarse_steps + int(outcome["steps"])
        run_time += time.perf_counter() - t0
    y, outcome = _canonical(problem, y, data.fixed, outcome)
    bar.update(3, "uncertainty and metrics")
    result = _finish(problem, model, measurements, data, y, outcome, starts=records, strategy=strategy,
                     times={"compile": compile_time, "run": run_time, "init": init_time})
    if result.status == "stalled" and isinstance(init, str) and init == "auto":
        result = _restart_stalled(measurements, result, problem, starts[best], kwargs)
    # Pruning is for fits that ran out of steps with a lobe drifting; a stalled fit's amplitude at 0 is the
    # stall itself, not evidence that the lobe is unneeded.
    if result.status == "max-steps":
        dead = _dead_amplitudes(problem, result.model.params, data, result.cost, result.dof)
        if dead:
            result = _refit_without(measurements, result, problem, dead, fixed_values, kwargs)
    bar.close(f"{result.status}, cost {result.cost:.6g}")
    if strict and not result.converged:
        raise FitError(f"fit of {result.spec} did not converge: {result.status}", result)
    return result


def _dead_amplitudes(problem: Problem, params: dict, data: FitData, cost: float, dof: int) -> list[str]:
    """Free amplitudes (colour scale parameters bounded by 0) whose lobe does not pay for its parameters: setting
    the amplitude to 0 raises χ² (the cost over the noise variance, cost/dof or 1 for ``loss="sigma"``) by at most
    twice the lobe's number of free scalars, AIC's price of those parameters (a useless lobe of k parameters
    fits away about k of χ² of pure noise)."""
    variance = 1.0 if problem.loss == "sigma" else cost / max(dof, 1)
    specs = problem.specs
    lobe_size = {}
    for names in global_names(problem.lobes):
        k = sum(int(np.size(params[n])) for n in names if n in problem.free)
        lobe_size.update({n: k for n in names})
    dead = []
    for name in problem.free:
        spec = specs[name]
        if not (spec.colour and spec.scale and spec.lower == 0):
            continue
        trial = dict(params, **{name: jnp.zeros_like(jnp.asarray(params[name]))})
        r = residual_fn(problem, trial, data)
        if float(jnp.sum(r * r)) - cost <= 2.0 * lobe_size[name] * variance:
            dead.append(name)
    return dead


def _restart_stalled(measurements, result: FitResult, problem: Problem, start: dict, kwargs: dict) -> FitResult:
    """The safeguard of ``init="auto"`` for a stalled fit: restart from where it stopped, with every scalar stuck
    on a bound put back at its starting value (or its declared default when the start was on the bound too),
    and keep the better of the two. A bound transform that saturated on the way (the gradient in the solver's
    variables vanishes there) is thereby undone; found by scripts/stability.py (near-mirror roughness, LM left
    ρd of two channels at 0)."""
    specs = problem.specs
    restart = {}
    for name in problem.free:
        spec = specs[name]
        value = np.array(result.params[name], dtype=float)
        stuck = np.asarray(at_bound(value, spec))
        if stuck.any():
            origin = np.broadcast_to(np.asarray(start[name], dtype=float), value.shape)
            inside = np.where(np.asarray(at_bound(origin, spec)), spec.default, origin)
            value = np.where(stuck, inside, value)
        restart[name] = value
    options = dict(kwargs, init=restart, multistart=0)
    options.pop("strict", None)
    again = fit(measurements, result.model, **options)
    if not again.cost < result.cost:
        return result
    again.starts = result.starts + again.starts
    again.warnings.insert(0, f"restarted from a stall with {', '.join(result.bounds_hit)} moved off the bound "
                             f"(cost {result.cost:.6g} -> {again.cost:.6g})")
    return again


def _refit_without(measurements, result: FitResult, problem: Problem, dead: list, fixed_values: dict,
                   kwargs: dict) -> FitResult:
    """Refit with the dead amplitudes held at 0 and the parameters that act only through them
    (`Lobe.amplitude_partners`) held where they are.

    A lobe that contributes nothing leaves its shape parameters undetermined; they drift and a step-size test
    never passes. Holding them makes the rest converge, and the status then reports the amplitude at its bound.
    """
    hold = {k: np.asarray(v) for k, v in fixed_values.items()}
    held_shapes = []
    for lobe, names in zip(problem.lobes, global_names(problem.lobes)):
        local_to_global = {spec.name: name for spec, name in zip(lobe.param_specs(), names)}
        for spec in lobe.param_specs():
            if local_to_global[spec.name] not in dead:
                continue
            hold[local_to_global[spec.name]] = 0.0
            for partner in lobe.amplitude_partners(spec.name):
                name = local_to_global[partner]
                if name in problem.free and name not in dead and name not in held_shapes:
                    hold[name] = np.asarray(result.params[name])
                    held_shapes.append(name)
    options = dict(kwargs, init=result.model, fixed=hold, multistart=0)
    options.pop("strict", None)
    again = fit(measurements, result.model, **options)
    note = (f"{', '.join(dead)} went to 0 in every channel: the lobe contributes nothing and was pruned "
            f"(amplitude held at 0{'; ' + ', '.join(held_shapes) + ' held where they were' if held_shapes else ''}); "
            "a model without it suffices")
    again.warnings.insert(0, note)
    if again.converged:
        again.status = "converged-at-bound"
        again.bounds_hit = list(again.bounds_hit) + [f"{name}[{c}]" for name in dead
                                                     for c in range(problem.channels)]
    again.starts = result.starts + again.starts
    return again


def _fit_independent(measurements, model, **kwargs) -> FitResult:
    """One shared-shape fit per channel, assembled: shape parameters become per-channel arrays."""
    channels = measurements.n_channels
    base = _resolve_model(model, channels)
    results = []
    for c in range(channels):
        single = get_model(base.spec, channels=1, **{
            name: (value[c:c + 1] if spec.colour else value)
            for (name, value), spec in zip(base.params.items(), base.param_specs)})
        results.append(fit(measurements.select_channels([c]), single, channel_mode="shared-shape", **kwargs))

    def merge(attr):
        merged = {}
        for name, spec in zip(base.params, base.param_specs):
            parts = [np.atleast_1d(np.asarray(getattr(r, attr)[name])) for r in results]
            merged[name] = np.concatenate(parts) if spec.colour else np.stack([p[0] for p in parts])
        return merged

    order = {"nonfinite": 3, "max-steps": 2, "converged-at-bound": 1, "converged": 0}
    worst = max((r.status for r in results), key=order.get)
    k = sum(r.n_params for r in results)
    n = sum(r.n_samples for r in results)
    cost = sum(r.cost for r in results)
    aic, bic = _information_criteria(results[0].loss, cost, n, k)
    labels = [f"{label}@{c}" for c, r in enumerate(results) for label in r.labels]
    size = len(labels)
    cov = np.zeros((size, size))
    cor = np.zeros((size, size))
    offset = 0
    for r in results:
        s = len(r.labels)
        cov[offset:offset + s, offset:offset + s] = r.covariance
        cor[offset:offset + s, offset:offset + s] = r.correlation
        offset += s
    return FitResult(
        model=None, params=merge("params"), stderr=merge("stderr"), stderr_robust=merge("stderr_robust"),
        covariance=cov, correlation=cor,
        labels=labels, metrics={m: np.concatenate([r.metrics[m] for r in results]) for m in results[0].metrics},
        n_samples=n, n_params=k, dof=n - k, cost=cost, aic=aic, bic=bic, status=worst,
        bounds_hit=[f"{b}@{c}" for c, r in enumerate(results) for b in r.bounds_hit],
        warnings=[f"channel {c}: {w}" for c, r in enumerate(results) for w in r.warnings],
        steps=max(r.steps for r in results), compile_time=sum(r.compile_time for r in results),
        run_time=sum(r.run_time for r in results), init_time=sum(r.init_time for r in results),
        loss=results[0].loss, solver=results[0].solver, channel_mode="independent", fixed=results[0].fixed,
        starts=[s for r in results for s in r.starts], noise_variance=float(np.mean([r.noise_variance
                                                                                      for r in results])),
        strategy=results[0].strategy, models=[r.model for r in results],
    )


def fit_many(measurements_list, model, *, loss: str = "cosine", solver="lm", init="auto", fixed=None,
             free=None, robust=None, max_steps: int = 256, rtol: float = 1e-8, atol: float = 1e-12, seed: int = 0,
             ) -> list[FitResult]:
    """Fit one model to many equally shaped data sets in one vmapped, jitted solve.

    This is the path for databases and spatially varying materials: every data set must have the same number of
    samples and channels (missing samples may differ). Each gets its own initial guess; the solves run together.

    Arguments:
        measurements_list: a sequence of `brdffit.Measurements` of equal shape.
        model, loss, solver, init, fixed, free, robust, max_steps, rtol, atol, seed: as for `fit`.

    Returns:
        One `FitResult` per data set, in order; each has the same answer as `fit` on that data set alone.
    """
    items = list(measurements_list)
    if not items:
        raise ValueError("fit_many needs at least one data set")
    shape = np.shape(items[0].values)
    for i, m in enumerate(items):
        if np.shape(m.values) != shape:
            raise ValueError(f"fit_many needs equally shaped data sets: item 0 has values of shape {shape}, "
                             f"item {i} has {np.shape(m.values)}; fit them separately with fit()")
    rtol, atol = working_tolerances(rtol, atol)
    prepared = [_prepare(m, model, loss=loss, solver=solver, fixed=fixed, free=free, robust=robust,
                         max_steps=max_steps, rtol=rtol, atol=atol) for m in items]
    problem = prepared[0][0]
    t0 = time.perf_counter()
    datas, firsts = [], []
    for m, (_, base_model, fixed_values, robust_scale) in zip(items, prepared):
        starts, eps, scale = _starting_points(problem, base_model, m, fixed_values, init, 0, seed, robust_scale)
        datas.append(make_fit_data(m, fixed_values, eps, scale))
        firsts.append(starts[0])
    init_time = (time.perf_counter() - t0) / len(items)
    y0 = _unconstrained(problem, firsts)
    data = stack_data(datas)
    executable, compile_time = compiled_solve(problem, y0, data, data_batched=True)
    t0 = time.perf_counter()
    out = jax.tree_util.tree_map(np.asarray, jax.block_until_ready(executable(y0, data)))
    run_time = (time.perf_counter() - t0) / len(items)
    results = []
    for i, (m, d, start) in enumerate(zip(items, datas, firsts)):
        outcome = {k: v[i] for k, v in out.items() if k != "y"}
        y_i, outcome = _canonical(problem, {k: v[i] for k, v in out["y"].items()}, d.fixed, outcome)
        record = [{"init": _json_params(start), "cost": float(outcome["cost"]), "status": _start_status(outcome),
                   "steps": int(outcome["steps"])}]
        results.append(_finish(problem, prepared[i][1], m, d, y_i, outcome,
                               starts=record,
                               times={"compile": compile_time, "run": run_time, "init": init_time}))
    return results
