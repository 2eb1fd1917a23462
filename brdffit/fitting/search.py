"""The global start of a fit: a coarse search over the declared bounds of the nonlinear parameters.

With the amplitudes projected out (`brdffit.fitting.separable`) a fit has one to a few nonlinear unknowns, few
enough to search globally before any local solve:

1. candidates: a grid over each outer scalar's declared range (log-spaced for scale parameters, cells centred so
   that the bounds' neighbourhoods are covered), or a scrambled Sobol set when the grid would exceed
   `MAX_CANDIDATES`; plus the model's own values and the lobes' own suggestions (`Lobe.start_candidates`, e.g.
   Lafortune lobes started forward, off-specular and retro at increasing sharpness), or the caller's candidates;
2. every candidate is scored in one batched, jitted pass on a seeded subsample of at most `SEARCH_SAMPLES`
   samples, its amplitudes solved exactly (for a nonlinear loss: with the loss linearised at the data, then
   scored by the true loss);
3. the `POLISH_STARTS` best candidates that lie apart from each other (in the unit cube of the search ranges)
   become the starts that the solver polishes together; the lowest polished cost wins.

A colour parameter that is not linear (a conductor's η and k) is searched as one value shared by the channels,
which the polish then separates.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..arrays import for_calls, host_arrays
from ..params import bound_margin
from .losses import get_loss
from .problem import FitData, Problem, residual_fn, sample_pieces
from ..programs import Program
from .separable import amplitude_sums, same_in_every_channel, solve_box

__all__ = ["search", "grid", "interior", "canonical", "search_range", "SEARCH_SAMPLES", "SCREEN_SAMPLES",
           "MAX_CANDIDATES", "POLISH_STARTS"]

SEARCH_SAMPLES = 4000
POLISH_STARTS = 4
# With more than SCREEN_ABOVE candidates and more than twice SCREEN_SAMPLES samples, every candidate is first
# scored on a seeded subsample of SCREEN_SAMPLES samples (a screen), and only the SCREEN_KEEP best of each material
# are scored again on the search's subsample, which chooses the starts from them as before: unscreened, a fit_many
# material of Lambert + GGX on 2,000 samples scores its ~320 candidates on all of them, a large share of its time
# after compilation. Twice the polish's starts are kept: keeping 16 instead of 8 found no better optimum in any of
# the 60 pairs of the misspecification matrix at 2,000 samples (where the screen runs), and rescored twice as many.
SCREEN_SAMPLES = 512
SCREEN_KEEP = 2 * POLISH_STARTS
# Screen costs within this relative difference of the last kept one are ties that the screen's rounding would
# break: those candidates are scored again too, up to SCREEN_TIES candidates a material. A spike lobe between the
# screen's samples fits the one sample nearest its peak with an amplitude of 1e14-1e72 and costs, to rounding,
# what every other such spike costs (Ashikhmin-Shirley data and one Lafortune lobe: 9 tied candidates, of which
# the rescoring on all samples, where the spikes differ, kept 8 chosen by rounding).
SCREEN_TIE = 1e-9
SCREEN_TIES = 4 * SCREEN_KEEP
# Candidates of one scoring call; with SCREEN_SAMPLES samples a call, the one compiled shape of a search.
SCORE_WIDTH = SCREEN_KEEP
MAX_CANDIDATES = 256
# Candidates closer than this in the unit cube of the search ranges count as the same basin.
_MIN_SEPARATION = 0.12
SCREEN_ABOVE = 64


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


def search_range(spec) -> tuple[float, float]:
    """Interval searched for a parameter: its bounds, narrowed to 1/100..10⁶ times the default for an unbounded
    scale parameter (an exponent n in (0, ∞) with default 20 is searched over 0.2..2·10⁷: a misspecified lobe
    often fits best as a spike far sharper than any default, down to one on the single sample nearest its peak,
    n ~ 1/δ² for a sample δ rad away; Ashikhmin-Shirley's optimum on 500 Blinn-Phong samples is n = 2·10⁷) and
    to ±10 scales around the default for an unbounded other one."""
    if spec.scale:
        lo = spec.lower if spec.lower > 0 else spec.default / 100.0
        hi = spec.upper if math.isfinite(spec.upper) else spec.default * 1e6
    else:
        width = 10.0 * max(abs(spec.default), 1.0)
        lo = spec.lower if math.isfinite(spec.lower) else spec.default - width
        hi = spec.upper if math.isfinite(spec.upper) else spec.default + width
    return float(lo), float(hi)


def _log_axis(spec) -> bool:
    return spec.scale and search_range(spec)[0] > 0


def _from_unit(u, spec) -> float:
    lo, hi = search_range(spec)
    if _log_axis(spec):
        return float(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo))))
    return float(lo + u * (hi - lo))


def _to_units(values, spec) -> np.ndarray:
    """Where ``values`` (one a candidate; a colour parameter's channels averaged) lie in ``spec``'s search range,
    as fractions of it (of its logarithm for a scale parameter), clipped to [0, 1]."""
    lo, hi = search_range(spec)
    values = np.asarray(values, dtype=float)
    if _log_axis(spec):
        return np.clip((np.log(np.maximum(values, lo)) - np.log(lo)) / (np.log(hi) - np.log(lo)), 0.0, 1.0)
    return np.clip((values - lo) / (hi - lo), 0.0, 1.0)


def _grid_units(d: int, seed: int, count: int = MAX_CANDIDATES) -> np.ndarray:
    """Points of the unit cube: a centred grid of up to 32 points per axis within ``count`` points (one to three
    dimensions), else ``count`` scrambled Sobol points, which cover more dimensions better than 4 or fewer levels per
    axis."""
    per_axis = min(32, int(math.floor(count ** (1.0 / d) + 1e-9)))
    if per_axis >= 5:
        axes = [(np.arange(per_axis) + 0.5) / per_axis for _ in range(d)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    from scipy.stats import qmc  # here, not at import: scipy.stats is slow to import

    return qmc.Sobol(d, scramble=True, seed=seed).random(count)


def grid(specs: list, seed: int, count: int = MAX_CANDIDATES) -> list[dict]:
    """Settings of the named scalars on the search's grid over their search ranges (`_grid_units`).

    Arguments:
        specs: the `ParamSpec`s of the searched scalars.
        seed: seed of the Sobol points (four or more scalars).
        count: the most points.

    Returns:
        A list of dicts name -> physical value (empty for no scalars).
    """
    if not specs:
        return []
    return [{s.name: _from_unit(u[k], s) for k, s in enumerate(specs)} for u in _grid_units(len(specs), seed, count)]


def _lobe_candidates(problem: Problem, names: set, seed: int) -> list[dict]:
    """The lobes' own start candidates (`Lobe.start_candidates`) under model-level names, combined across lobes
    (at most `MAX_CANDIDATES`, a seeded choice when there are more)."""
    per_lobe = []
    for j, lobe in enumerate(problem.lobes):
        starts = [{k: v for k, v in problem.layout.global_names(j, c).items() if k in names}
                  for c in lobe.start_candidates()]
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


def canonical(problem: Problem, params: dict) -> dict:
    """The parameters in each lobe's canonical order (`Lobe.canonical`, e.g. Lafortune lobes sorted by n)."""
    out = dict(params)
    for j, lobe in enumerate(problem.lobes):
        out.update(problem.layout.global_names(j, lobe.canonical(problem.layout.local_params(params, j))))
    return out


def quasi_random_starts(problem: Problem, count: int, seed: int) -> list[dict]:
    """``count`` scrambled-Sobol points over the outer parameters' search ranges (the extra starts of
    ``multistart``)."""
    specs = [problem.specs[name] for name in dataclasses.replace(problem, separable=True).outer]
    if not specs or count <= 0:
        return []
    # A power-of-two draw keeps Sobol's balance (and scipy quiet); the first `count` points are used.
    from scipy.stats import qmc

    units = qmc.Sobol(len(specs), scramble=True, seed=seed + 1).random_base2(max(count - 1, 0).bit_length())[:count]
    return [{s.name: _from_unit(u[k], s) for k, s in enumerate(specs)} for u in units]


def _materials_a_step(materials: int) -> int:
    """The materials of a batch that the search's program scores together: one on a CPU, whose cache holds one
    material's (candidates × samples) intermediates but not a batch's (`_over_materials`); all of them on an
    accelerator, whose parallelism needs them."""
    return 1 if jax.default_backend() == "cpu" else materials


def _over_materials(one, name: str) -> Program:
    """``one(params, data)`` of one candidate and one material, compiled for ``(M, B)`` candidates and data with a
    leading material axis M: the candidates vmapped, the materials `_materials_a_step` at a time in the program
    (``lax.map``): one after another on a CPU, where vmapped over the materials too, the ``(M, B, N)``
    intermediates of a `fit_many` batch left the cache (its search ran markedly slower; 1, 2 or 4 materials a
    step ran alike; docs/benchmarks.md)."""
    per_material = jax.vmap(one, in_axes=(0, None))

    @functools.wraps(one)  # its name in JAX's logs and profiles
    def over_materials(params, data):
        materials = jax.tree_util.tree_leaves(data)[0].shape[0]
        return jax.lax.map(lambda args: per_material(*args), (params, data),
                           batch_size=_materials_a_step(materials))

    return Program(over_materials, name)


@functools.lru_cache(maxsize=64)
def _sums_fn(problem: Problem, shared: bool):
    """Compiled ``(candidates, data) -> (c0, gram, rhs)`` of the weighted amplitude problem of every candidate:
    ``c0`` ``(M, B, C)`` the squared norm of w·(f_d − f₀), ``gram`` ``(M, B, C, K, K)`` and ``rhs``
    ``(M, B, C, K)`` its normal equations (`brdffit.fitting.separable.amplitude_sums`, with the basis of one
    channel for every channel where ``shared``: `_channel_shared`), for B candidates of each of
    M materials (candidates ``(M, B) + shape``, data with a leading material axis). The bounded solve runs on the
    host: enumerated on the device it held 3^K unrolled systems per candidate, whose compilation outweighed the
    rest of the program's."""
    def one(params, data: FitData):
        return amplitude_sums(problem, params, problem.linear, data, shared=shared)

    return _over_materials(one, f"search {'shared ' if shared else ''}sums {problem!r}")


def _channel_shared(problem: Problem, batches: list) -> bool:
    """Whether every colour parameter but the projected amplitudes has one value in all channels in every
    candidate of ``batches`` (`_batches`): then the amplitudes' basis is the same in every channel and is
    evaluated once (`brdffit.fitting.separable.amplitude_sums`). So it is in a search, which gives a colour
    parameter that is not linear one value for all channels; a caller's start or fixed values may not."""
    return all(same_in_every_channel(problem, batch) for _, batch in batches)


@functools.lru_cache(maxsize=64)
def _cost_fn(problem: Problem):
    """Compiled ``(candidates, data) -> (costs (M, B),)``: the loss at complete parameters (amplitudes given),
    for the losses whose cost is not the quadratic of the projection (nonlinear, robust); shapes as
    `_sums_fn`'s."""
    def one(params, data: FitData):
        r = residual_fn(problem, params, data)
        return (jnp.sum(r * r),)

    return _over_materials(one, f"search costs {problem!r}")


def _batches(candidates: list, materials: int, width: int) -> list[tuple[int, dict]]:
    """The candidates in chunks of ``width`` (the last padded by repeating its last), each stacked on the host
    for every material: ``(count, {name: (M, width) + shape})``. ``candidates`` is one list of dicts for every
    material, or a list of such lists, one a material (equally long)."""
    per_material = isinstance(candidates[0], list)
    total = len(candidates[0]) if per_material else len(candidates)
    out = []
    for start in range(0, total, width):
        def stacked(listed):
            chunk = listed[start:start + width]
            padded = chunk + [chunk[-1]] * (width - len(chunk))
            return {k: np.stack([np.asarray(d[k], dtype=float) for d in padded]) for k in padded[0]}

        if per_material:
            chunks = [stacked(listed) for listed in candidates]
            batch = {k: np.stack([chunk[k] for chunk in chunks]) for k in chunks[0]}
        else:
            batch = {k: np.broadcast_to(v, (materials,) + v.shape) for k, v in stacked(candidates).items()}
        out.append((min(width, total - start), batch))
    return out


def score(problem: Problem, candidates: list, data: FitData, width: int = SCORE_WIDTH,
          piece: int | None = SCREEN_SAMPLES):
    """Costs of full-parameter candidates with their amplitudes solved, for each material.

    The device forms each candidate's normal equations in its amplitudes, piece by piece of the samples (the sums
    add); the host solves them within the bounds (`brdffit.fitting.separable.solve_box`) and, for a linear loss,
    reads the cost off the same sums: ‖w(f₀ + Ba − f_d)‖² = c₀ − 2aᵀb + aᵀGa. A nonlinear loss or a robust one is
    scored by its own residuals at the solved amplitudes. One call scores ``width`` candidates of every material
    on one piece of ``piece`` samples, so that one compiled shape per batch size serves every subsample of a
    search: the screen, the rescoring and an unscreened search (else each subsample size would compile its own
    for every candidate model of a first selection), and a `fit_many` batch of M materials makes as many calls as
    one material (called material by material, the calls' dispatch and the data's transfers were a sizeable share of
    a `fit_many`).

    Arguments:
        problem: the problem, with `separable` set for the scoring (amplitudes projected with the loss's
            weights, linearised at the data for a nonlinear loss).
        candidates: dicts of physical values of every parameter, the same for every material; or, for each
            material, its own list of such dicts (equally many).
        data: `FitData` with a leading material axis.
        width: the candidates scored by one call of the compiled program.
        piece: the samples of one call (the last piece padded with masked samples); None: all of them at once.

    Returns:
        ``(costs (M, B), amplitudes)``: amplitudes name -> ``(M, B, C)``.
    """
    names = problem.linear
    quadratic = get_loss(problem.loss).linear and problem.robust is None
    specs = problem.specs
    lower, upper = [specs[a].lower for a in names], [specs[a].upper for a in names]
    materials, n = np.shape(data.values)[:2]
    batches = _batches(candidates, materials, width)
    # Each piece is read by every batch's call of the sums' program and, scored by the loss itself, of the cost's.
    calls = len(batches) * (bool(names) + (not (names and quadratic)))
    pieces = [for_calls(p, calls) for p in sample_pieces(data, n if piece is None else piece)]

    def added(program, params):  # a program's outputs summed over the pieces, on the host, cut to the chunk
        params = host_arrays(params)
        outputs = [program(params, p) for p in pieces]
        return [sum(np.asarray(out[j], dtype=float) for out in outputs) for j in range(len(outputs[0]))]

    amplitudes = {}
    if names:
        # Every candidate's sums on the device, then one bounded solve of them all.
        sums = _sums_fn(problem.structure, _channel_shared(problem, batches))
        outs = [[a[:, :count] for a in added(sums, batch)] for count, batch in batches]
        c0, gram, rhs = (np.concatenate([out[j] for out in outs], axis=1) for j in range(3))
        a = solve_box(gram, rhs, lower, upper)  # (M, B, C, K)
        amplitudes = {name: a[..., k] for k, name in enumerate(names)}
    if names and quadratic:
        return np.sum(c0 - 2.0 * np.sum(a * rhs, axis=-1) + np.einsum("...k,...kl,...l->...", a, gram, a),
                      axis=-1), amplitudes
    # Scored by the loss itself at the solved amplitudes.
    costs, start = [], 0
    for count, batch in batches:
        solved = {name: _padded(value[:, start:start + count], width) for name, value in amplitudes.items()}
        costs.append(added(_cost_fn(problem.structure), dict(batch, **solved))[0][:, :count])
        start += count
    return np.concatenate(costs, axis=1), amplitudes


def _padded(values: np.ndarray, width: int) -> np.ndarray:
    """``values`` ``(M, B, ...)`` padded to ``width`` candidates by repeating the last (as `_batches` pads)."""
    return np.concatenate([values, np.repeat(values[:, -1:], width - values.shape[1], axis=1)], axis=1)


def _separated(costs, units, count: int, separation: float) -> list[int]:
    """Up to ``count`` finite candidates in order of cost, each farther than ``separation`` (in the unit cube of
    the search ranges, largest coordinate difference) from those picked before it."""
    picks: list[int] = []
    for index in np.argsort(costs, kind="stable"):
        if len(picks) == count or not np.isfinite(costs[index]):
            break
        if all(np.max(np.abs(units[index] - units[p]), initial=0.0) > separation for p in picks):
            picks.append(int(index))
    return picks


def _screened(problem: Problem, candidates: list[dict], data: FitData, screen: FitData, units, starts: int,
              separation: float):
    """`score` of all ``candidates`` on ``screen`` and of `SCREEN_KEEP` of them on ``data`` for each material:
    the best ``starts`` separated ones on the screen (`_separated`, so that the starts stay apart however the
    best candidates cluster), then the best of the rest; the others cost infinity (their amplitudes 0)."""
    rough, _ = score(problem, candidates, screen)
    rough = np.where(np.isfinite(rough), rough, np.inf)
    best = []
    for row in rough:
        keep = _separated(row, units, starts, separation)
        rest = [int(i) for i in np.argsort(row, kind="stable") if i not in keep]
        more = SCREEN_KEEP - len(keep)
        keep += rest[:more]
        if 0 < more < len(rest) and np.isfinite(row[rest[more - 1]]):  # and those the screen cannot tell from it
            last = row[rest[more - 1]]
            keep += [i for i in rest[more:] if row[i] <= last + SCREEN_TIE * abs(last)][:SCREEN_TIES - len(keep)]
        best.append(keep)
    width = max(len(keep) for keep in best)
    best = np.array([keep + keep[-1:] * (width - len(keep)) for keep in best])
    chosen, chosen_amplitudes = score(problem, [[candidates[i] for i in row] for row in best], data)
    rows = np.arange(rough.shape[0])[:, None]
    costs = np.full(rough.shape, np.inf)
    costs[rows, best] = chosen
    amplitudes = {}
    for name, value in chosen_amplitudes.items():
        amplitudes[name] = np.zeros(rough.shape + value.shape[2:])
        amplitudes[name][rows, best] = value
    return costs, amplitudes


def search(problem: Problem, base: dict, data: FitData, seed: int, candidates: list[dict] | None = None,
           starts: int = POLISH_STARTS, separation: float = _MIN_SEPARATION,
           screen: FitData | None = None, own_search: bool = False) -> list[list[dict]]:
    """The best separated candidates of each material, as starts for the polish.

    Arguments:
        problem: the `Problem` (its `outer` names are searched).
        base: physical values of every parameter (the model's own values; fixed ones are kept).
        data: `FitData` of a subsample (at most `SEARCH_SAMPLES` samples), leading material axis.
        seed: seed of the Sobol points and of the choice among the lobes' candidates.
        candidates: outer-parameter settings to score instead of the grid and the lobes' suggestions (missing
            names take their ``base`` values), or beside them with ``own_search``.
        starts: how many starts to return per material.
        separation: the least distance between two starts in the unit cube of the search ranges (negative:
            keep every candidate).
        screen: `FitData` of a smaller subsample (`SCREEN_SAMPLES`, same material axis), or None: with more
            than `SCREEN_ABOVE` candidates, each material's candidates are first scored on it, and the
            `SCREEN_KEEP` best are scored on ``data``; the others are not starts.
        own_search: score the grid and the lobes' suggestions after the given ``candidates``.

    Returns:
        For each material, up to ``starts`` dicts of physical values of every parameter (amplitudes solved),
        best first, each outer value moved inside its bounds.
    """
    specs = problem.specs
    scoring = dataclasses.replace(problem, separable=True)
    outer = [specs[name] for name in scoring.outer]
    base = {k: np.asarray(v, dtype=float) for k, v in base.items()}
    own = {s.name: base[s.name] for s in outer}
    settings = [own] + [{k: v for k, v in c.items() if k in own} for c in candidates or []]
    if candidates is None or own_search:
        settings += grid(outer, seed) + _lobe_candidates(problem, set(own), seed)
    full = []
    for setting in settings:
        params = dict(base)
        for name, value in setting.items():
            params[name] = np.broadcast_to(np.asarray(value, dtype=float), np.shape(base[name])).copy()
        full.append(params)
    # Equivalent settings (Lafortune lobes in another order) are one candidate: put each in canonical order.
    full = [canonical(problem, p) for p in full]
    units = np.zeros((len(full), len(outer)))
    for k, s in enumerate(outer):
        units[:, k] = _to_units([np.mean(p[s.name]) for p in full], s)
    if screen is not None and len(full) > SCREEN_ABOVE:
        costs, amplitudes = _screened(scoring, full, data, screen, units, starts, separation)
    else:
        costs, amplitudes = score(scoring, full, data)
    costs = np.where(np.isfinite(costs), costs, np.inf)
    chosen = []
    for m in range(costs.shape[0]):
        picks = _separated(costs[m], units, starts, separation) or [0]
        material = []
        for index in picks:
            params = dict(full[index], **{a: amplitudes[a][m, index] for a in amplitudes})
            for name in problem.outer:  # the solver's variables (amplitudes too in a joint solve)
                params[name] = interior(params[name], specs[name])
            material.append(params)
        chosen.append(material)
    return chosen

