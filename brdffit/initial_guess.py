"""Data-driven starting points for a fit (``init="auto"``) and the quasi-random extra starts of ``multistart``.

Most colour parameters (diffuse albedo, specular amplitudes, Schlick-weighted reflectances) enter a model
affinely. For a given setting of the shape parameters (roughness, exponents, ...) the best affine amplitudes are a
bounded linear least-squares problem. The initial guess therefore:

1. takes a seeded subsample of the valid data (at most `MAX_INIT_SAMPLES`);
2. proposes shape-parameter candidates: a grid over each free shape parameter's bounds (log-spaced for scale
   parameters), or Sobol points when the grid would be too large, plus the model's own values and the lobes'
   own suggestions (`Lobe.start_candidates`, e.g. Lafortune lobes started forward, off-specular and retro at
   increasing sharpness);
3. for each candidate solves the amplitudes per channel by bounded linear least squares in the fit's loss,
   linearised at the data (`scipy.optimize.lsq_linear`), which is where the diffuse level comes from the
   off-specular samples and the specular amplitude and width from the peak around the mirror direction;
4. ranks candidates by the true (nonlinear) loss of the resulting parameters and starts from the best one,
   preferring among nearly equal ones the candidate with the most amplitudes at zero.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import lsq_linear
from scipy.stats import qmc

from .models.model import evaluate_pair
from .losses import residual_scale
from .params import bound_margin
from .models.model import global_names
from .problem import FitData, Problem, residual_fn

__all__ = ["initial_guesses", "interior", "MAX_INIT_SAMPLES"]

MAX_INIT_SAMPLES = 10_000
MAX_CANDIDATES = 256
# Candidates whose cost is within this relative distance of the best count as equally good (see
# `_sparsest_near_best`).
SPARSE_TOLERANCE = 1e-3
_CHUNK = 32


def interior(value, spec):
    """Move a value at least 1e-3 of the parameter's scale inside its bounds, so that its transform has a usable
    gradient when a solver starts there.

    Arguments:
        value: physical value(s).
        spec: the parameter's `ParamSpec`.

    Returns:
        The nudged value(s) as a NumPy array.
    """
    value = np.asarray(value, dtype=float)
    margin = bound_margin(spec, 1e-3)
    lo = spec.lower + margin if math.isfinite(spec.lower) else -np.inf
    hi = spec.upper - margin if math.isfinite(spec.upper) else np.inf
    return np.clip(value, lo, hi)


def _search_range(spec):
    """Interval searched for a shape parameter: its bounds, narrowed to 1/100..100 times the default for an
    unbounded scale parameter and to ±10 scales around the default for an unbounded other one."""
    if spec.scale:
        lo = spec.lower if spec.lower > 0 else spec.default / 100.0
        hi = spec.upper if math.isfinite(spec.upper) else spec.default * 100.0
    else:
        width = 10.0 * max(abs(spec.default), 1.0)
        lo = spec.lower if math.isfinite(spec.lower) else spec.default - width
        hi = spec.upper if math.isfinite(spec.upper) else spec.default + width
    return float(lo), float(hi)


def _unit_to_value(u, spec):
    lo, hi = _search_range(spec)
    if spec.scale and lo > 0:
        return float(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo))))
    return float(lo + u * (hi - lo))


def _shape_candidates(shape_specs, base: dict, n_extra: int, seed: int) -> tuple[list[dict], list[dict]]:
    """Grid (or Sobol) candidates for the free shape parameters, and ``n_extra`` quasi-random extra starts."""
    d = len(shape_specs)
    own = {s.name: float(base[s.name]) for s in shape_specs}
    if d == 0:
        return [own], [own] * n_extra
    per_axis = max(2, min(9, int(round(MAX_CANDIDATES ** (1.0 / d)))))
    if per_axis ** d <= MAX_CANDIDATES:
        axes = [(np.arange(per_axis) + 0.5) / per_axis for _ in shape_specs]
        units = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    else:
        units = qmc.Sobol(d, scramble=True, seed=seed).random(MAX_CANDIDATES)
    grid = [own] + [{s.name: _unit_to_value(u[k], s) for k, s in enumerate(shape_specs)} for u in units]
    # A power-of-two draw keeps Sobol's balance (and scipy quiet); the first n_extra points are used.
    extra_units = qmc.Sobol(d, scramble=True, seed=seed + 1).random_base2(max(n_extra - 1, 0).bit_length())[:n_extra]
    extra = [{s.name: _unit_to_value(u[k], s) for k, s in enumerate(shape_specs)} for u in extra_units]
    return grid, extra


def _lobe_candidates(problem: Problem, free_shape: set, seed: int) -> list[dict]:
    """The lobes' own start candidates (`Lobe.start_candidates`) under model-level names, combined across lobes
    (at most `MAX_CANDIDATES`, a seeded choice when there are more)."""
    per_lobe = []
    for lobe, names in zip(problem.lobes, global_names(problem.lobes)):
        mapping = {spec.name: name for spec, name in zip(lobe.param_specs(), names)}
        starts = [{mapping[k]: v for k, v in c.items() if mapping[k] in free_shape} for c in lobe.start_candidates()]
        if starts:
            per_lobe.append(starts)
    if not per_lobe:
        return []
    sizes = [len(c) for c in per_lobe]
    total = int(np.prod(sizes))
    rng = np.random.default_rng(seed)
    picks = range(total) if total <= MAX_CANDIDATES else rng.choice(total, MAX_CANDIDATES, replace=False)
    combined = []
    for flat in picks:
        merged = {}
        for starts, index in zip(per_lobe, np.unravel_index(int(flat), sizes)):
            merged.update(starts[index])
        combined.append(merged)
    return combined


def _is_affine(problem: Problem, base: dict, name: str, data: FitData) -> bool:
    """True if the model is affine in colour parameter ``name`` (checked numerically at three values)."""
    trials = [dict(base, **{name: np.full(problem.channels, v)}) for v in (0.0, 0.5, 1.0)]
    f0, f1, f2 = _batched(_eval_fn, problem, trials, data)
    scale = np.max(np.abs(f2)) + 1e-300
    return bool(np.all(np.isfinite(f2)) and np.max(np.abs(f2 - 2 * f1 + f0)) <= 1e-9 * scale)


@functools.lru_cache(maxsize=64)
def _eval_fn(problem: Problem):
    """Jitted model values ``(B, N, C)`` for a batch of parameter dicts (leading axis B on every value)."""
    return jax.jit(jax.vmap(lambda params, data: evaluate_pair(problem.model(params), data.pair),
                            in_axes=(0, None)))


@functools.lru_cache(maxsize=64)
def _cost_fn(problem: Problem):
    """Jitted summed squared residuals ``(B,)`` for a batch of parameter dicts."""
    def one(params, data):
        r = residual_fn(problem, params, data)
        return jnp.sum(r * r)

    return jax.jit(jax.vmap(one, in_axes=(0, None)))


def _batched(fn, problem: Problem, dicts: list[dict], data: FitData) -> np.ndarray:
    """Apply a batched function in chunks of `_CHUNK` (the last padded) so that one compilation serves all."""
    out = []
    for start in range(0, len(dicts), _CHUNK):
        chunk = dicts[start:start + _CHUNK]
        padded = chunk + [chunk[-1]] * (_CHUNK - len(chunk))
        # Stack on the host and transfer once per name (a device array per dict cost ~0.1 s per guess).
        batch = {k: jnp.asarray(np.stack([np.asarray(d[k], dtype=float) for d in padded])) for k in padded[0]}
        out.append(np.asarray(fn(problem)(batch, data))[: len(chunk)])
    return np.concatenate(out)


def _fill_amplitudes(problem: Problem, shape_sets: list[dict], base: dict, affine: list, data: FitData,
                     weights: np.ndarray) -> list[dict]:
    """For each shape-parameter set, the full parameter dict with affine amplitudes solved per channel."""
    specs = problem.specs
    channels = problem.channels
    full = [dict(base, **shape) for shape in shape_sets]
    if not affine or not full:
        return full
    zero = [dict(p, **{a: np.zeros(channels) for a in affine}) for p in full]
    f_zero = _batched(_eval_fn, problem, zero, data)
    basis = np.stack([_batched(_eval_fn, problem, [dict(p, **{a: np.ones(channels)}) for p in zero], data) - f_zero
                      for a in affine], axis=-1)  # (B, N, C, K)
    values = np.asarray(data.values)
    bounds = (np.array([specs[a].lower for a in affine]), np.array([specs[a].upper for a in affine]))
    results = []
    for b, params in enumerate(full):
        solved = {a: np.full(channels, specs[a].default) for a in affine}
        for c in range(channels):
            keep = weights[:, c] > 0
            A = basis[b, keep, c, :] * weights[keep, c, None]
            rhs = (values[keep, c] - f_zero[b, keep, c]) * weights[keep, c]
            if A.shape[0] == 0 or not (np.all(np.isfinite(A)) and np.all(np.isfinite(rhs))):
                continue
            x = lsq_linear(A, rhs, bounds=bounds, method="bvls").x
            for k, a in enumerate(affine):
                solved[a][c] = x[k]
        results.append(dict(params, **solved))
    return results


def _sparsest_near_best(candidates: list[dict], costs: np.ndarray, affine: list) -> int:
    """Index of the candidate to start from: among those within `SPARSE_TOLERANCE` of the lowest cost, the one
    with the most amplitudes at zero (then the lowest cost). A lobe the data do not need then starts switched
    off, rather than as a copy of another lobe that shares its work (a flat valley solvers crawl along)."""
    best = float(np.min(costs))
    near = np.flatnonzero(costs <= best * (1.0 + SPARSE_TOLERANCE) + 1e-300)
    zeros = [sum(bool(np.all(np.asarray(candidates[i][a]) == 0.0)) for a in affine) for i in near]
    order = sorted(range(len(near)), key=lambda k: (-zeros[k], costs[near[k]]))
    return int(near[order[0]])


def initial_guesses(problem: Problem, base: dict, data: FitData, n_extra: int, seed: int,
                    candidates: list[dict] | None = None) -> list[dict]:
    """Starting points for a fit: the best data-driven guess first, then ``n_extra`` quasi-random starts.

    Arguments:
        problem: the `Problem` (which parameters are free, the loss).
        base: physical values of every parameter (the model's values; fixed ones are kept).
        data: `FitData` of a subsample of the measurements (at most `MAX_INIT_SAMPLES` samples).
        n_extra: number of extra starts (``multistart``).
        seed: seed of the quasi-random sequences.
        candidates: shape-parameter settings to score instead of the grid and the lobes' suggestions (missing
            names take their ``base`` values); amplitudes are solved for each as usual.

    Returns:
        A list of ``1 + n_extra`` dicts name -> physical value (NumPy), each moved inside the bounds.
    """
    specs = problem.specs
    free = set(problem.free)
    base = {k: np.asarray(v, dtype=float) for k, v in base.items()}
    shape_specs = [s for s in specs if s.name in free and not s.colour]
    colour_free = [s.name for s in specs if s.name in free and s.colour]
    affine = [a for a in colour_free if _is_affine(problem, base, a, data)]
    grid, extra = _shape_candidates(shape_specs, base, n_extra, seed)
    if candidates is not None:
        shape_names = {s.name for s in shape_specs}
        grid = [grid[0]] + [{k: v for k, v in c.items() if k in shape_names} for c in candidates]
    else:
        grid = grid + _lobe_candidates(problem, {s.name for s in shape_specs}, seed)
    weights = residual_scale(problem.loss, data)
    candidates = _fill_amplitudes(problem, grid, base, affine, data, weights)
    costs = _batched(_cost_fn, problem, candidates, data)
    costs = np.where(np.isfinite(costs), costs, np.inf)
    best = candidates[_sparsest_near_best(candidates, costs, affine)]
    starts = [best] + _fill_amplitudes(problem, extra, base, affine, data, weights)
    return [{k: interior(v, specs[k]) if k in free else v for k, v in s.items()} for s in starts]
