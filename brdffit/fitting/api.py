"""`fit` and `fit_many`: one pipeline for one material, many materials and independent channels (docs/fitting.md).

The pipeline, step by step, for a batch of equally shaped materials (`fit` is a batch of one; independent
channels are a batch of single-channel materials):

1. **prepare**: validate the options, build the `Problem` (amplitudes projected whenever the loss is linear and
   no robust rewrite is asked, `brdffit.fitting.separable`) and the data arrays;
2. **search**: score a grid of the nonlinear parameters over their declared bounds, amplitudes solved at each, on a
   subsample; the best separated candidates become the starts (`brdffit.fitting.search`);
3. **polish**: all starts of all materials solved together, each solve's outcome a `SolveOutcome`: by the
   engine's Levenberg-Marquardt over compiled passes (`brdffit.fitting.marquardt`, the default) or one vmapped
   optimistix solve (on a subsample first when the data are large); the solver's answer is kept;
4. **hold**: a polish that did not converge because an outer parameter runs into a bound (its transform
   saturates) or a lobe whose amplitudes all went to 0 leaves its shape drifting is solved again with those
   parameters held (on the bound, or where they are); the better answer is kept, and the bound stays visible in
   the status;
   a fit still not converged then has its least useful lobe pruned if that lobe does not pay for itself;
5. **refine**: large data are refined on all samples (`brdffit.fitting.marquardt`, from next to the optimum);
6. **diagnose and report**: canonical lobe order, the status with its Karush-Kuhn-Tucker test, standard errors
   (`brdffit.fitting.uncertainty`), warnings, metrics and information criteria.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from ..arrays import host_arrays, on_device, to_device
from ..blas_threads import one_blas_thread
from ..defaults import FIT
from ..metrics import fit_sums, metrics_from_sums
from ..models.model import Model
from ..models.registry import get as get_model
from ..params import at_bound
from ..progress import Progress
from .losses import ROBUST, get_loss, loss_epsilon
from . import marquardt, noise
from .normal_equations import chunks, timed
from .problem import FitData, Problem, make_fit_data, residuals_at, stack_data, take_materials, take_samples
from .outcome import SolveOutcome, Status
from .result import FitResult
from .search import (SCREEN_SAMPLES, SEARCH_SAMPLES, canonical, grid, interior, quasi_random_starts,
                     score, search, search_range)
from .solvers import batch_solver, coarse_solver, make_solver, solver_name, working_tolerances
from .status import diagnose, information_criteria, warnings_of
from .uncertainty import Uncertainty, normal_equations_at

__all__ = ["fit", "fit_many", "FitError", "CHANNEL_MODES"]

CHANNEL_MODES = ("shared-shape", "independent")
# Data with more (sample, channel) values than COARSE_RESIDUALS is first solved on a seeded subsample of
# COARSE_SAMPLES samples and then refined on all of it (`brdffit.fitting.marquardt`). Below it one stage is
# faster from a new process: the refinement's pass is a second compiled shape.
COARSE_RESIDUALS = 150_000
COARSE_SAMPLES = 10_000
COARSE_RTOL, COARSE_ATOL = 1e-5, 1e-8
# A sub-lobe searched again (`_revive`): its best separated settings are polished for PROBE_STEPS steps, and the
# lowest of them, where it is still moving and already REVIVE_GAIN below the answer, goes on alone up to
# REVIVE_STEPS steps in all. The probe tells the new basins apart (a spike that catches the samples at the mirror
# peak is below the answer within 16 steps where it ends below it) at a quarter of a full revival's passes; the
# polishes it follows converge in 20-60 steps from the search's starts, a spike's exponent in up to 100, and a
# revival that does not converge is discarded (its steps are lost time).
PROBE_STEPS = 16
REVIVE_STEPS = 128
# The least relative gain for which a revival replaces the answer (and a probe goes on): the precision to which a
# fit claims the optimum (`tests/test_misspecification.py`). Smaller gains are a lobe turned into a spike on the
# noise of one sample (a spare Lafortune lobe of amplitude 1e81 on one of 1,500 samples: 2e-4 lower), or the same
# optimum (two Lafortune lobes on the RGL-EPFL paper: a probe 1e-7 below its answer went on for 112 steps to it).
REVIVE_GAIN = 1e-3
# The most grid points over one sub-lobe's shape in a revival (an 8 x 8 grid for a Lafortune lobe's cxy and n):
# the search's 256 found the same optima in the tests' misspecified Lafortune sums, or a higher one (three lobes
# on Blinn-Phong data of one seed: 5.9 % above the reference with 256, 0.6 % with 64), and scored four times as many.
REVIVE_GRID = 64
# A lobe is pruned only if zeroing it raises the cost by at most this fraction (and by AIC's price,
# `_dead_amplitudes`): a pruned fit stays within this fraction of the optimum's cost.
PRUNE_COST_FRACTION = 1e-3
# The full-data refinement (step 5) starts within the subsample's statistical error of the optimum (three passes
# on a MERL table): a small initial damping. Its step limit is the fit's.
REFINE_DAMPING = 1e-6
# Rounds of holding and releasing bounds (an active-set iteration) before the pipeline reports what it has.
HOLD_ROUNDS = 3


class FitError(RuntimeError):
    """Raised by a strict fit that did not converge; ``.result`` holds the `FitResult`."""

    def __init__(self, message: str, result: FitResult):
        super().__init__(message)
        self.result = result


# ------------------------------------------------------------------------------------------------------- prepare
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


def _prepare(measurements, model, *, loss, solver, fixed, free, robust, max_steps, rtol, atol):
    """Validate the arguments and build the `Problem`, the base model, the fixed values and the robust scale."""
    declared = get_loss(loss)
    if declared.needs_sigma and measurements.sigma is None:
        raise ValueError(f"loss={loss!r} needs measurements with per-sample sigma; these have none")
    robust_kind, robust_scale = _parse_robust(robust)
    model = _resolve_model(model, measurements.n_channels)
    fixed_values = _split_fixed(model, fixed, free)
    problem = Problem(
        lobes=model.lobes, channels=model.channels,
        free=tuple(s.name for s in model.param_specs if s.name not in fixed_values),
        loss=loss, robust=robust_kind, solver=make_solver(solver, rtol, atol), max_steps=int(max_steps),
        separable=declared.linear and robust_kind is None,
    )
    return problem, model, fixed_values, robust_scale


def _use_coarse(coarse, measurements) -> bool:
    if coarse not in ("auto", True, False):
        raise ValueError(f"coarse must be 'auto', True or False, got {coarse!r}")
    if coarse == "auto":
        return measurements.n * measurements.n_channels > COARSE_RESIDUALS and measurements.n > COARSE_SAMPLES
    return bool(coarse) and measurements.n > COARSE_SAMPLES


def _json_params(params: dict) -> dict:
    return {k: np.asarray(v, dtype=float).tolist() for k, v in params.items()}


# -------------------------------------------------------------------------------------------------------- search
def _starts(problem: Problem, model: Model, fixed_values: dict, init, multistart: int, seed: int,
            data: FitData, screen: FitData | None) -> list[list[dict]]:
    """The starts of every material (physical values of every parameter, amplitudes solved), equally many
    (``screen``: the search's screening subsample, `brdffit.fitting.search.search`)."""
    base = dict(model.params, **fixed_values)
    materials = int(np.shape(data.values)[0])
    extra = quasi_random_starts(problem, multistart, seed)

    def scored(settings):  # the settings with their amplitudes solved, in the given order
        return search(problem, base, data, seed, candidates=settings, starts=len(settings) + 1, separation=-1.0)

    if isinstance(init, str) and init == "auto":
        starts = search(problem, base, data, seed, screen=screen)
    elif isinstance(init, list):
        own_search = bool(init) and isinstance(init[-1], str) and init[-1] == "auto"
        candidates = init[:-1] if own_search else init
        if not all(isinstance(c, dict) for c in candidates):
            raise ValueError(f"init as a list takes dicts of shape settings, optionally ending in 'auto', got "
                             f"{init!r}")
        starts = search(problem, base, data, seed, candidates=candidates, screen=screen, own_search=own_search)
    elif isinstance(init, str) and init == "model" or isinstance(init, (dict, Model)):
        if isinstance(init, (dict, Model)):
            given = init.params if isinstance(init, Model) else model.replace(**init).params
            base = dict(base, **{k: v for k, v in given.items() if k not in fixed_values})
        # The given values start the solve (a separable one solves the amplitudes itself).
        starts = [[dict(base)] for _ in range(materials)]
    else:
        raise ValueError(f"init must be 'auto', 'model', a Model, a dict of values or a list of candidate "
                         f"shape settings (optionally ending in 'auto'), got {init!r}")
    if extra:
        for material, more in zip(starts, scored(extra)):
            material.extend(more[:len(extra)])
    count = max(len(s) for s in starts)
    return [s + [s[-1]] * (count - len(s)) for s in starts]


def _robust_scale(problem: Problem, start: dict, data: FitData) -> float:
    """1.4826 times the median absolute residual at the start (the robust loss's default scale)."""
    plain = dataclasses.replace(problem, robust=None)
    r = np.asarray(residuals_at(plain, start, data))
    mask = np.asarray(data.mask)
    return float(max(1.4826 * np.median(np.abs(r[mask])), 1e-12)) if mask.any() else 1.0


# -------------------------------------------------------------------------------------------------------- polish
def _polish(problem: Problem, starts: list[list[dict]], data: FitData, held: list[dict] | None = None,
            metrics: bool = False, max_steps: int | None = None):
    """Solve every start of every material: the projection alone where nothing nonlinear is free, else the
    problem's solver through its `brdffit.fitting.solvers.BatchSolver` interface.

    Arguments:
        problem: the `Problem`.
        starts: for each material, its starts (physical values of every parameter).
        data: `FitData` with a leading material axis.
        held: for each material, outer name -> physical value to hold (a NaN entry holds nothing), the same for
            every start of that material.
        metrics: ``data`` is the whole data: let the default solver give the metric sums of its answers too.
        max_steps: a step limit below the problem's (the default solver only; the problem's structure, and so
            the compiled programs, stay the same).

    Returns:
        ``(outcomes, compile_seconds, run_seconds)``: for each material a list of one `SolveOutcome` a start
        (with ``normal``, ``exact`` and ``answer`` from the default solver, `brdffit.fitting.marquardt.solve`).
    """
    if not problem.outer:  # nothing nonlinear is free: the projection is the whole solve
        t0 = time.perf_counter()
        # The fixed values are the same for every material; one candidate on all the samples at once.
        costs, amplitudes = score(problem, [starts[0][0]], data, width=1, piece=None)
        out = []
        for m, material in enumerate(starts):
            params = dict(material[0], **{a: amplitudes[a][m, 0] for a in amplitudes})
            out.append([SolveOutcome(params, float(costs[m, 0]), nonfinite=not np.isfinite(costs[m, 0]))])
        return out, 0.0, time.perf_counter() - t0
    solve_data = data._replace(fixed={k: to_device(np.stack([np.asarray(material[0][k], dtype=float)
                                                               for material in starts]))
                                      for k in problem.layout.names if k not in problem.free})
    return batch_solver(problem.solver).solve_starts(problem, starts, solve_data, held=held, metrics=metrics,
                                                     max_steps=max_steps)


def _normal(problem: Problem, outcome: SolveOutcome, data: FitData):
    """The normal equations at an outcome: the solver's own when it gave them, else a pass over ``data``."""
    if not problem.free:
        return None
    if outcome.normal is not None:
        return outcome.normal
    return normal_equations_at(problem, outcome.params, data)


def _answered(outcome: SolveOutcome, params: dict) -> bool:
    """Whether the solver's sums of an outcome on the whole data serve as those of the answer ``params``: they
    carry the metric sums, the solver's last pass evaluated the point itself (``exact``), and the canonical order
    left the parameters as they were (a reordering of lobes would move the Jacobian's columns)."""
    normal = outcome.normal
    return (normal is not None and normal.metric_sums is not None and outcome.exact
            and all(np.array_equal(np.asarray(params[k]), np.asarray(outcome.params[k])) for k in params))


def _best(outcomes: list[SolveOutcome]) -> SolveOutcome:
    """The outcome the polish answers with: the one the default solver marked as its answer, else
    `brdffit.fitting.marquardt.answer`'s (the lowest cost, or a start that converged within `BEST_TIE` of it
    rather than one that ran out of steps). The solver's mark stands: its final pass at the answer can move that
    cost by rounding above another start's at the same optimum (whose sums then are not the answer's: a further
    pass, a new compiled shape in a `fit_many` worker)."""
    marked = [o for o in outcomes if o.answer and not o.nonfinite]
    if marked:
        return marked[0]
    costs = np.array([np.inf if o.nonfinite else o.cost for o in outcomes])
    return outcomes[marquardt.answer(costs, np.array([o.max_steps for o in outcomes]))]


# ---------------------------------------------------------------------------------------------------------- hold
def _to_hold(problem: Problem, params: dict) -> dict:
    """Outer parameters to hold for a re-solve: scalars within `brdffit.fitting.marquardt.BOUND_FRACTION` of a
    bound (snapped onto it), an exponent below its search range (held on its bound 0), and the shape of lobes whose
    amplitudes are all 0 (held where they are). NaN marks a scalar left free."""
    layout = problem.layout
    held = {}
    for name in problem.outer:
        spec = layout[name].spec
        value = np.array(params[name], dtype=float)
        near = np.asarray(at_bound(value, spec, marquardt.BOUND_FRACTION))
        if spec.scale and spec.lower == 0.0:
            # A cosine power max(0, d)^n with n below its search range (1/100 of its default) is, for the data, a
            # step function of its half-space: its direction (Lafortune's cxy) has a tangent n·d^(n−1) only on the
            # few samples at the edge, and none at n = 0. The solver stalls there (three Lafortune lobes on
            # Blinn-Phong data at n = 0.045, the Gauss-Newton step pointing along cxy); on the bound the lobe is
            # the step function itself, and the status names n.
            near |= value < search_range(spec)[0]
        if near.any():
            nearest = np.where(np.abs(value - spec.lower) <= np.abs(value - spec.upper), spec.lower, spec.upper)
            held[name] = np.where(near, nearest, np.nan)
    for _, _, names in _shape_groups(problem, params, dead=True):
        held.update({name: np.asarray(params[name], dtype=float) for name in names})
    return held


def _shape_groups(problem: Problem, params: dict, dead: bool) -> list[tuple[int, str, tuple[str, ...]]]:
    """The shapes of the sub-lobes: for each projected amplitude (every one, or with ``dead`` those whose values
    all went to 0) that has outer names acting only through it (`Layout.partners`), ``(lobe index, the
    amplitude's local name, those names)``."""
    layout, groups = problem.layout, []
    for j in range(len(problem.lobes)):
        for slot in layout.lobe_slots(j):
            if slot.name in problem.linear and (not dead or np.all(np.asarray(params[slot.name]) == 0.0)):
                names = tuple(name for name in layout.partners(j, slot.local) if name in problem.outer)
                if names:
                    groups.append((j, slot.local, names))
    return groups


def _next_holds(problem: Problem, held: dict, params: dict, jtr) -> dict:
    """The holds of the next round after a re-solve (an active-set update): a scalar held on a bound whose descent
    direction −∂cost/∂p points into the box is released (its entry becomes NaN), a scalar the re-solve took to a
    bound is added (`_to_hold`), scalars held inside the box (a dead lobe's shape) stay. Empty when nothing
    changed: another round would repeat this one."""
    offsets = problem.layout.offsets(problem.free)
    changed, out = False, {}
    for name, value in held.items():
        spec = problem.specs[name]
        value = np.array(value, dtype=float)
        gradient = np.reshape(np.asarray(jtr)[offsets[name]], value.shape)
        inward = ((value == spec.lower) & (gradient < 0)) | ((value == spec.upper) & (gradient > 0))
        changed |= bool(inward.any())
        out[name] = np.where(inward, np.nan, value)
    for name, value in _to_hold(problem, params).items():
        before = np.broadcast_to(out.get(name, np.nan), np.shape(value))
        was_held = np.isfinite(np.broadcast_to(np.asarray(held.get(name, np.nan), dtype=float), np.shape(value)))
        added = np.isnan(before) & np.isfinite(value) & ~was_held  # a scalar just released stays free
        if added.any():
            changed = True
            out[name] = np.where(added, value, before)
    return out if changed else {}


def _held_start(problem: Problem, params: dict, held: dict) -> dict:
    """The start of a re-solve: the held scalars on their values, the other outer ones moved inside the bounds."""
    start = dict(params)
    for name in problem.outer:
        inside = interior(params[name], problem.specs[name])
        start[name] = np.where(np.isfinite(held[name]), held[name], inside) if name in held else inside
    return start


# -------------------------------------------------------------------------------------------------------- revive
def _revive(problem: Problem, solve_problem: Problem, kept: SolveOutcome, search_data: FitData,
            screen_data: FitData | None, material: int, data: FitData, seed: int, starts: int, metrics: bool,
            dead: bool) -> tuple[SolveOutcome | None, float, float]:
    """Search sub-lobes' shapes again, the rest of one material's answer held: a grid over each one's shape
    parameters (`search.grid`) and the lobe's own suggestions for it (`Lobe.sub_lobe_candidates`, e.g. a Lafortune
    spike on the mirror direction), every amplitude re-solved at each setting, the best separated settings
    polished with everything free (`PROBE_STEPS`, then the lowest alone up to `REVIVE_STEPS`). This is the nested
    search of Lafortune et al. (1997) and Ngan et al. (2005), who add lobes one after another, done for the
    sub-lobes whose amplitudes all went to 0 (``dead``), or for every sub-lobe of a model with two or more shaped
    sub-lobes: a polish of all lobes at once can end with one lobe dead while another place for it lowers the cost
    (three Lafortune lobes on Cook-Torrance data: 0.7 % lower), or with a lobe in one of the many minima of a sum
    of lobes that the first search's joint grid could not tell apart (two Lafortune lobes on anisotropic GGX data
    of one seed: 6.8 % above the optimum, the sharp lobe at the mirror missed). With a single shaped sub-lobe the
    first search was already such a search.

    Arguments:
        problem, solve_problem: the `Problem` and the one that polishes (a looser solver on a coarse stage).
        kept: the material's best outcome so far.
        search_data, screen_data: the search's subsamples and screening subsamples (or None) of every material
            (material axis).
        material: the material's index in ``search_data``.
        data: the material's polish data (no material axis).
        seed: the fit's seed.
        starts: the polish's number of starts.
        metrics: ``data`` is the whole data (`_polish`).
        dead: search the sub-lobes whose amplitudes all went to 0, else every shaped sub-lobe where there are two or
            more.

    Returns:
        ``(outcome, compile_seconds, run_seconds)``: the best revived outcome, with a note, when it converged at
        least `REVIVE_GAIN` below ``kept``'s cost, else None; and the seconds the polish spent either way.
    """
    groups = _shape_groups(problem, kept.params, dead)
    if not groups or not dead and len(groups) < 2:
        return None, 0.0, 0.0
    specs, layout = problem.specs, problem.layout
    candidates = []
    for j, amplitude, names in groups:
        candidates += grid([specs[n] for n in names], seed, REVIVE_GRID)
        suggested = problem.lobes[j].sub_lobe_candidates(amplitude, layout.local_params(kept.params, j))
        candidates += [{k: v for k, v in layout.global_names(j, c).items() if k in names} for c in suggested]
    single = take_materials(search_data, [material])
    screen = None if screen_data is None else take_materials(screen_data, [material])
    found = search(problem, kept.params, single, seed, candidates=candidates, starts=starts, screen=screen)
    polish_data = stack_data([data])
    outcomes, compile_time, run_time = _polish(solve_problem, found, polish_data, metrics=metrics,
                                               max_steps=min(solve_problem.max_steps, PROBE_STEPS))
    revived = _best(outcomes[0])
    left = min(solve_problem.max_steps, REVIVE_STEPS) - revived.steps
    if revived.max_steps and left > 0 and revived.cost < kept.cost * (1.0 - REVIVE_GAIN):
        more, more_compile, more_run = _polish(solve_problem, [[revived.params]], polish_data, metrics=metrics,
                                               max_steps=left)
        compile_time, run_time = compile_time + more_compile, run_time + more_run
        revived = dataclasses.replace(more[0][0], steps=more[0][0].steps + revived.steps)
    # Only a converged answer replaces one: a lower point still moving after REVIVE_STEPS lies in a flat valley
    # (two GGX lobes sharing f0 on paper_white: 0.15 % lower after 256 steps, not converged).
    if revived.max_steps or revived.nonfinite or not revived.cost < kept.cost * (1.0 - REVIVE_GAIN):
        return None, compile_time, run_time
    shapes = '; '.join(', '.join(names) for _, _, names in groups)
    why = "where their lobe's amplitudes had all gone to 0" if dead else "each with the others held"
    revived = dataclasses.replace(revived, steps=revived.steps + kept.steps, notes=kept.notes + (
        f"{shapes} searched again {why} (cost {kept.cost:.6g} -> {revived.cost:.6g})",))
    return revived, compile_time, run_time


# --------------------------------------------------------------------------------------------------------- prune
def _dead_amplitudes(problem: Problem, params: dict, cost: float, data: FitData) -> list[str]:
    """Projected amplitudes whose lobe does not pay for its parameters: setting the amplitude to 0 raises χ² (the
    cost over the noise variance, cost/dof or 1 for ``loss="sigma"``) by at most twice the lobe's number of free
    scalars, AIC's price of those parameters (a useless lobe of k parameters fits away about k of χ² of noise),
    and by at most `PRUNE_COST_FRACTION` of the cost, so that a pruned fit stays that close to the optimum.
    Only amplitudes not already 0 everywhere are tested, and never the only lobe's; of those that qualify, the
    one whose removal costs least."""
    if len(problem.lobes) < 2 or not problem.linear:
        return []
    layout = problem.layout
    n_valid = int(np.sum(np.asarray(data.mask)))
    k = layout.size(problem.free)
    variance = 1.0 if problem.loss == "sigma" else cost / max(n_valid - k, 1)
    increases = {}
    for j in range(len(problem.lobes)):
        for slot in layout.lobe_slots(j):
            if slot.name not in problem.linear or np.all(np.asarray(params[slot.name]) == 0.0):
                continue
            partners = layout.partners(j, slot.local)
            size = layout[slot.name].size + layout.size([n for n in partners if n in problem.outer])
            trial = dict(params, **{slot.name: np.zeros(layout[slot.name].shape)})
            r = np.asarray(residuals_at(problem, trial, data))
            increase = float(np.sum(r * r)) - cost
            if increase <= min(2.0 * size * variance, PRUNE_COST_FRACTION * cost):
                increases[slot.name] = float(increase)
    # One lobe at a time, the one that matters least: two copies of a lobe each look dispensable while the other
    # is there.
    return [min(increases, key=increases.get)] if increases else []


def _prune(problem: Problem, solve_problem: Problem, kept: SolveOutcome, dead: list, data: FitData, starts: int,
           metrics: bool):
    """Solve one material again with the ``dead`` amplitudes held at 0 and the parameters that act only through
    them (`Lobe.amplitude_partners`) held where they are: a problem with fewer free parameters."""
    layout = problem.layout
    held = {name: np.zeros(layout[name].shape) for name in dead}
    for j in range(len(problem.lobes)):
        for slot in layout.lobe_slots(j):
            if slot.name in dead:
                for name in layout.partners(j, slot.local):
                    if name in problem.free and name not in dead:
                        held[name] = np.asarray(kept.params[name], dtype=float)
    free = tuple(n for n in problem.free if n not in held)
    reduced = dataclasses.replace(problem, free=free)
    start = dict(kept.params, **held)
    start = {k: (interior(v, problem.specs[k]) if k in reduced.outer else v) for k, v in start.items()}
    single = stack_data([data])
    single = single._replace(fixed={k: to_device(np.asarray(v)[None]) for k, v in start.items() if k not in free})
    outcomes, compile_time, run_time = _polish(dataclasses.replace(solve_problem, free=free), [[start] * starts],
                                               single, metrics=metrics)
    pruned = _best(outcomes[0])
    pruned = dataclasses.replace(pruned, steps=pruned.steps + kept.steps, pruned=tuple(dead), notes=kept.notes + (
        f"{', '.join(dead)} went to 0 in every channel: the lobe contributes nothing and was pruned (amplitude "
        f"held at 0; {', '.join(sorted(set(held) - set(dead))) or 'nothing else'} held where it was); a model "
        "without it suffices",))
    return reduced, pruned, compile_time, run_time


# ---------------------------------------------------------------------------------------------------- the result
def _result(problem: Problem, model: Model, measurements, data: FitData, params: dict, outcome: SolveOutcome, normal,
            starts: list, times: dict, strategy: str, moved: dict) -> FitResult:
    """Diagnose the kept solution of one material and build its `FitResult` (``moved``: ``params`` on the device,
    a batch's answers moved together: a transfer each would add a dispatch per material to a `fit_many`)."""
    params = {k: np.asarray(v) for k, v in params.items()}
    fitted = model.replace(**moved)
    layout = problem.layout
    valid = np.isfinite(measurements.values)
    n_valid = int(valid.sum())
    cost = float(normal.cost) if normal is not None else float(outcome.cost)
    if problem.free:
        status, hit, decrease = diagnose(problem, params, cost, outcome.max_steps, outcome.nonfinite,
                                         normal.jtj, normal.jtr)
    else:
        status, hit, decrease = (Status.NONFINITE if not np.isfinite(cost) else Status.CONVERGED), [], 0.0
    if n_valid <= 0:
        status = Status.NONFINITE
    pruned = [label for name in outcome.pruned for label in layout[name].labels()]
    if pruned and status == Status.CONVERGED:
        status = Status.CONVERGED_AT_BOUND
    hit = hit + pruned
    channel_cost = normal.channel_cost if normal is not None else np.full(problem.channels, cost / problem.channels)
    sums = normal.metric_sums if normal is not None else fit_sums(fitted, measurements, pair=data.pair)
    # The noise model the residuals support decides which covariance the result reports (docs/fitting.md).
    noise_model = noise.of_fit(problem, sums, data, channel_cost, n_valid)
    uncertainty = Uncertainty(normal if problem.free else None, cost, problem.loss, n_valid, problem=problem,
                              noise=noise_model, channel_counts=valid.sum(axis=0))
    labels = layout.labels(problem.free)
    warnings = warnings_of(problem, labels, uncertainty, hit, status, decrease, cost, params)
    warnings = list(outcome.notes) + warnings
    k = len(labels)
    aic, bic = information_criteria(problem.loss, cost, n_valid, k)
    metrics = {"rmse_loss": np.sqrt(channel_cost / np.maximum(valid.sum(axis=0), 1))}
    metrics.update(metrics_from_sums(sums))
    covariance, correlation, stderr = uncertainty.chosen(noise_model.covariance)

    def per_param(flat):
        offsets = layout.offsets(problem.free)
        return {name: (np.reshape(flat[offsets[name]], layout[name].shape) if name in offsets
                       else np.zeros(layout[name].shape)) for name in layout.names}

    return FitResult(
        model=fitted, params=dict(fitted.params), stderr=per_param(stderr),
        stderr_laplace=per_param(uncertainty.stderr), stderr_robust=per_param(uncertainty.stderr_robust),
        covariance=covariance, correlation=correlation, labels=labels, metrics=metrics, n_samples=n_valid,
        n_params=k,
        dof=n_valid - k, cost=cost, aic=aic, bic=bic, status=status, bounds_hit=hit, warnings=warnings,
        steps=int(outcome.steps), compile_time=times["compile"], run_time=times["run"], init_time=times["init"],
        loss=problem.loss, solver=solver_name(problem.solver), channel_mode="shared-shape",
        fixed=sorted(n for n in layout.names if n not in problem.free), starts=starts,
        noise_variance=float(uncertainty.variance), strategy=strategy, models=[fitted], noise_model=noise_model,
        theta_i_max=float(np.max(measurements.theta_i, initial=0.0)),
    )


# ------------------------------------------------------------------------------------------------------ pipeline
@dataclasses.dataclass
class _Material:
    """One material's state between the pipeline's stages.

    Attributes:
        problem: its problem (pruning takes parameters out of it).
        kept: its answer so far.
        records: one record per start and per later solve (`FitResult.starts`).
        normal: the normal equations at ``kept`` on the solve data (`_assess` onwards).
        status: ``kept``'s diagnosed status (`_assess` onwards).
        holds: outer name -> value to hold in the next hold round (NaN: free); empty when no round is due.
    """

    problem: Problem
    kept: SolveOutcome
    records: list
    normal: object = None
    status: Status | None = None
    holds: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class _Run:
    """What every stage of one run of the pipeline shares.

    Attributes:
        problem: the problem as prepared; ``solve_problem`` the one that polishes (a looser solver on a coarse
            stage).
        two_stage: the polish runs on a coarse subsample and the answer is refined on all the data.
        full, solve_items: every material's data, whole and as the polish sees it (no material axis).
        search_data: the search's subsamples (material axis).
        screen_data: the search's screening subsamples (material axis), or None (`brdffit.fitting.search.search`).
        searched: the starts came from a search (``init`` "auto" or a list of candidates) and the fit searches
            each shaped sub-lobe again (``lobe_search``).
        starts: the number of starts a material (the polish's width).
        seed, rtol, atol: the fit's.
        bar: the progress line.
        compile_time, run_time: seconds spent so far, summed over the stages.
    """

    problem: Problem
    solve_problem: Problem
    two_stage: bool
    full: list
    solve_items: list
    search_data: FitData
    screen_data: FitData | None
    searched: bool
    starts: int
    seed: int
    rtol: float
    atol: float
    bar: Progress
    compile_time: float = 0.0
    run_time: float = 0.0

    def spent(self, compile_time: float, run_time: float) -> None:
        self.compile_time += compile_time
        self.run_time += run_time

    @property
    def metrics(self) -> bool:
        """Whether the polish sees the whole data (then the default solver gives its answer's metric sums)."""
        return not self.two_stage


def _record(start: dict, outcome: SolveOutcome, status: Status | None = None, **stage) -> dict:
    """One entry of `FitResult.starts`: a solve's start, its cost, status (the solver's own unless diagnosed) and
    steps, and what the stage that made it did (``revived``, ``held``, ``pruned``)."""
    return {"init": _json_params(start), "cost": outcome.cost, "status": outcome.status if status is None else status,
            "steps": outcome.steps, **stage}


def _polish_stage(run: _Run, starts: list[list[dict]]) -> list[_Material]:
    """Stage 3: polish every start of every material; each material keeps its solver's answer."""
    run.bar.update(1, f"polishing {run.starts} start{'s' if run.starts > 1 else ''}"
                      f"{f' on {COARSE_SAMPLES} samples' if run.two_stage else ''}")
    outcomes, compile_time, run_time = _polish(run.solve_problem, starts, stack_data(run.solve_items),
                                               metrics=run.metrics)
    run.spent(compile_time, run_time)
    return [_Material(run.problem, _best(o), [_record(s, a) for s, a in zip(material_starts, o)])
            for material_starts, o in zip(starts, outcomes)]


def _revive_stage(run: _Run, materials: list[_Material]) -> list[_Material]:
    """Sub-lobes searched again with the rest held (`_revive`), material by material: those whose amplitudes all
    went to 0, then, after a search, each shaped sub-lobe of a model with several."""
    for m, material in enumerate(materials):
        for dead in (True, False) if run.searched else (True,):
            revived, compile_time, run_time = _revive(run.problem, run.solve_problem, material.kept, run.search_data,
                                                      run.screen_data, m, run.solve_items[m], run.seed, run.starts,
                                                      run.metrics, dead)
            run.spent(compile_time, run_time)
            if revived is not None:
                material.records.append(_record(material.kept.params, revived, revived=True))
                material.kept = revived
    return materials


def _assess(run: _Run, materials: list[_Material]) -> list[_Material]:
    """Each answer's normal equations and status on the solve data, and what a hold round would hold."""
    problem = run.problem
    for material, data in zip(materials, run.solve_items):
        kept = material.kept
        material.normal = _normal(problem, kept, data)
        material.status = diagnose(problem, kept.params, kept.cost, kept.max_steps, kept.nonfinite,
                                   material.normal.jtj, material.normal.jtr)[0] if problem.free else Status.CONVERGED
        material.holds = _to_hold(problem, kept.params) if material.status.unfinished else {}
    return materials


def _hold_stage(run: _Run, materials: list[_Material]) -> list[_Material]:
    """Stage 4: up to `HOLD_ROUNDS` re-solves with the parameters on a bound (or of a dead lobe) held, an
    active-set update between rounds; a retry replaces the answer when it is lower or converged."""
    problem = run.problem
    for _ in range(HOLD_ROUNDS):
        if not any(material.holds for material in materials):
            break
        run.bar.update(2, "holding parameters and solving again")
        holds = [material.holds for material in materials]
        again, compile_time, run_time = _polish(
            run.solve_problem, [[_held_start(problem, material.kept.params, h)] * run.starts
                                for material, h in zip(materials, holds)],
            stack_data(run.solve_items), holds, metrics=run.metrics)
        run.spent(compile_time, run_time)
        for m, (material, held) in enumerate(zip(materials, holds)):
            if not held:
                continue
            retry = again[m][0]
            retry_normal = _normal(problem, retry, run.solve_items[m])
            retry_status = diagnose(problem, retry.params, retry.cost, retry.max_steps, retry.nonfinite,
                                    retry_normal.jtj, retry_normal.jtr)[0]
            kept = material.kept
            material.records.append(_record(_held_start(problem, kept.params, held), retry, retry_status,
                                            held=sorted(held)))
            if retry.cost <= kept.cost or retry_status.converged:
                retry = dataclasses.replace(retry, steps=retry.steps + kept.steps, notes=kept.notes + (
                    f"{', '.join(sorted(held))} held (on a bound, or where a lobe whose amplitudes all went to 0 "
                    f"left them) after a solve that ended {material.status} "
                    f"(cost {kept.cost:.6g} -> {retry.cost:.6g})",))
                material.kept, material.normal, material.status = retry, retry_normal, retry_status
            # The active-set update: a held bound whose descent direction points into the box (Karush-Kuhn-Tucker)
            # is released, a scalar the re-solve took to a bound is added.
            material.holds = _next_holds(problem, held, retry.params, retry_normal.jtr) \
                if material.status.unfinished else {}
    return materials


def _prune_stage(run: _Run, materials: list[_Material]) -> list[_Material]:
    """Stage 4, last: a solve that still did not converge has its least useful lobe pruned (`_dead_amplitudes`,
    `_prune`). A converged fit's spare lobe is the least-squares answer: selection, not the fit, decides whether
    it is worth its parameters."""
    for m, material in enumerate(materials):
        dead = _dead_amplitudes(run.problem, material.kept.params, material.kept.cost, run.solve_items[m]) \
            if material.status.unfinished else []
        if not dead:
            continue
        run.bar.update(2, f"pruning {', '.join(dead)}")
        material.problem, pruned, compile_time, run_time = _prune(run.problem, run.solve_problem, material.kept,
                                                                  dead, run.solve_items[m], run.starts, run.metrics)
        run.spent(compile_time, run_time)
        material.records.append(_record(pruned.params, pruned, pruned=dead))
        material.kept = pruned
        material.normal = _normal(material.problem, pruned, run.solve_items[m])
    return materials


def _answer(run: _Run, material: _Material, measurements, data: FitData) -> tuple:
    """Stage 5 and the answer's sums: on a coarse stage, the answer refined on all the data (the default
    solver's steps from next to the optimum, small initial λ, whatever solver polished); then the normal
    equations at the answer itself (the solver's last pass where it evaluated the answer, else one more pass).

    Returns:
        ``(params, outcome, normal)``: the answer's parameters in canonical lobe order, its outcome and sums.
    """
    best, normal, problem = material.kept, material.normal, material.problem
    params = canonical(problem, best.params)
    if run.two_stage:
        run.bar.update(3, f"refining on all {measurements.n} samples")
        fixed = data._replace(fixed={k: to_device(v) for k, v in params.items() if k not in problem.free})
        refined, compile_time, run_time = timed(lambda: marquardt.solve(
            problem, [[params]], chunks(fixed), rtol=run.rtol, atol=run.atol, max_steps=problem.max_steps,
            damping=REFINE_DAMPING, metrics=True)[0][0])
        run.spent(compile_time, run_time)
        best = dataclasses.replace(best, params=refined.params, cost=refined.cost, steps=best.steps + refined.steps,
                                   max_steps=refined.max_steps, nonfinite=refined.nonfinite, normal=refined.normal,
                                   exact=refined.exact)
        params = canonical(problem, refined.params)
    if not problem.free:
        r = np.asarray(residuals_at(problem, params, data))
        best = dataclasses.replace(best, cost=float(np.sum(r * r)))
    elif _answered(best, params):
        normal = best.normal
    else:
        # A pass at the answer itself, where the solver's last sums are not those of the answer. It gives the
        # status, the covariance and the metrics.
        width = 1 if run.two_stage else marquardt.polish_width(run.starts, data.values.shape[0])
        normal = normal_equations_at(problem, params, data, width=width)
    return params, best, normal


def _pipeline(items: list, model, *, loss, solver, init, fixed, free, multistart, robust, max_steps, rtol, atol,
              seed, coarse, lobe_search, bar: Progress) -> list[FitResult]:
    """The fitting pipeline of the module doc over equally shaped materials ``items``: prepare and search here,
    then the stages (`_polish_stage`, `_revive_stage`, `_assess`, `_hold_stage`, `_prune_stage`, `_answer`)
    on a `_Material` state each, then `_result`."""
    for measurements in items:  # no information, no fit: it would end "converged" at its start
        measurements.check_informative()
    rtol, atol = working_tolerances(rtol, atol)
    problem, base_model, fixed_values, robust_scale = _prepare(
        items[0], model, loss=loss, solver=solver, fixed=fixed, free=free, robust=robust, max_steps=max_steps,
        rtol=rtol, atol=atol)
    if not isinstance(multistart, int) or isinstance(multistart, bool) or multistart < 0:
        raise ValueError(f"multistart must be a non-negative integer, got {multistart!r}")
    if not isinstance(lobe_search, bool):
        raise ValueError(f"lobe_search must be True or False, got {lobe_search!r}")
    eps = [loss_epsilon(loss, m.values) for m in items]
    two_stage = bool(problem.outer) and _use_coarse(coarse, items[0])
    strategy = f"coarse ({COARSE_SAMPLES} samples) + refine" if two_stage else "full"

    bar.update(0, "search")
    t0 = time.perf_counter()

    # The data's arrays stay NumPy until `stack_data` moves a stack of them (every subsample is cut from `full`).
    full = [make_fit_data(m, fixed_values, e, 1.0, pad=True, device=False) for m, e in zip(items, eps)]

    def subsample(m, limit):
        rows = items[m].subsample_rows(limit, seed=seed)
        return full[m] if rows is None else take_samples(full[m], rows)

    def subsampled(limit):
        return stack_data([subsample(m, limit) for m in range(len(items))])

    search_data = subsampled(SEARCH_SAMPLES)
    # The screen pays where it scores on at most half of the search's samples (and only a search uses it).
    searching = isinstance(init, list) or isinstance(init, str) and init == "auto"
    screen_data = subsampled(SCREEN_SAMPLES) if searching and items[0].n > 2 * SCREEN_SAMPLES else None
    starts = _starts(problem, base_model, fixed_values, init, multistart, seed, search_data, screen_data)
    if problem.robust is not None and robust_scale is None:
        scales = [_robust_scale(problem, s[0], jax.tree_util.tree_map(lambda a, m=m: a[m], search_data))
                  for m, s in enumerate(starts)]
    else:
        scales = [robust_scale if robust_scale is not None else 1.0] * len(items)
    init_time = time.perf_counter() - t0

    full = [d._replace(robust_scale=host_arrays(float(s))) for d, s in zip(full, scales)]
    if two_stage:
        solve_items = [subsample(m, COARSE_SAMPLES) for m in range(len(items))]
        loose = coarse_solver(solver, max(COARSE_RTOL, rtol), max(COARSE_ATOL, atol)) \
            if isinstance(solver, str) else problem.solver
        solve_problem = dataclasses.replace(problem, solver=loose)
    else:
        solve_items, solve_problem = full, problem
    run = _Run(problem, solve_problem, two_stage, full, solve_items, search_data, screen_data,
               searching and lobe_search, len(starts[0]), seed, rtol, atol, bar)
    materials = _polish_stage(run, starts)
    for stage in (_revive_stage, _assess, _hold_stage, _prune_stage):
        materials = stage(run, materials)
    answers = [_answer(run, material, measurements, data)
               for material, measurements, data in zip(materials, items, full)]
    times = {"compile": run.compile_time, "run": run.run_time / len(items), "init": init_time / len(items)}
    moved = on_device([{k: np.asarray(v, dtype=float) for k, v in params.items()} for params, _, _ in answers])
    return [_result(material.problem, base_model, measurements, data, params, best, normal, material.records,
                    times, strategy, on_the_device)
            for material, measurements, data, (params, best, normal), on_the_device
            in zip(materials, items, full, answers, moved)]


# ---------------------------------------------------------------------------------------------------- public API
@one_blas_thread()
def fit(measurements, model=None, *, loss: str = FIT.loss, solver=FIT.solver, init="auto", fixed=None, free=None,
        multistart: int = 0, channel_mode: str = "shared-shape", robust=None, max_steps: int = FIT.max_steps,
        rtol: float = FIT.rtol, atol: float = FIT.atol, seed: int = FIT.seed, coarse="auto",
        lobe_search: bool = True, strict: bool = False, target: str | None = None,
        progress: bool = False) -> FitResult:
    """Fit a model to measurements by least squares: amplitudes exactly, the rest by a global search and a
    polish (the pipeline of the module doc).

    Arguments:
        measurements: `brdffit.Measurements`.
        model: a spec string (``"lambert+ggx"``) or a `Model` (its values are the start when ``init="model"``);
            None with a ``target``.
        loss: a name in `brdffit.fitting.losses.LOSSES`: ``"cosine"`` (default), ``"log"``, ``"relative"``,
            ``"absolute"`` or ``"sigma"`` (docs/fitting.md).
        solver: a name from `brdffit.fitting.solvers.SOLVERS` (``"lm"``, ``"gauss-newton"``, ``"dogleg"``,
            ``"indirect-lm"``, ``"bfgs"``) or any optimistix least-squares solver or minimiser; it moves the
            nonlinear parameters (the amplitudes are projected out for a linear loss).
        init: ``"auto"`` (global search over the declared bounds, `brdffit.fitting.search`), ``"model"`` (the
            model's values), a `Model`, a dict of starting values, or a list of candidate settings of the
            nonlinear parameters (dicts) that the search scores instead of its own grid; a list ending in
            ``"auto"`` is scored before the search's own candidates, not instead of them.
        fixed: parameters held fixed: a dict name -> value, or names held at the model's values.
        free: names of parameters declared fixed by default (e.g. the toon ``width``) that this fit frees.
        multistart: extra quasi-random starts over the bounds, polished with the others in one vmapped solve; the
            lowest cost is kept and every start is recorded in ``result.starts``.
        channel_mode: ``"shared-shape"`` (colour parameters per channel, shape parameters shared and fitted
            jointly) or ``"independent"`` (one fit per channel, all solved in one batch).
        robust: None, ``"huber"``, ``"cauchy"`` or ``(kind, scale)``; without a scale it is 1.4826 times the
            median absolute residual at the start.
        max_steps: the solver's step limit.
        rtol, atol: the solver's convergence tolerances (optimistix's Cauchy termination), raised to what the
            working precision can meet (`brdffit.fitting.solvers.working_tolerances`; changes nothing in float64).
        seed: seed of the subsamples and of the quasi-random starts.
        coarse: ``"auto"`` solves data with more than `COARSE_RESIDUALS` values on a seeded subsample of
            `COARSE_SAMPLES` samples first and then refines on all of it (`brdffit.fitting.marquardt`); True forces
            and False disables this. The answer is the full-data optimum either way; only the time differs.
        lobe_search: after the polish of a search's starts, search each shaped sub-lobe of a model that has two or
            more again with the others held, and polish what lowers the cost (`_revive`: the nested search of
            Lafortune et al. 1997 and Ngan et al. 2005); False leaves it to the sub-lobes whose amplitudes all
            went to 0 (`brdffit.select`'s screens, for time).
        strict: raise `FitError` instead of returning a non-converged result.
        progress: report the stages (search, polish, hold, refinement, uncertainty) on a progress line on stderr
            (`brdffit.progress.Progress`).
        target: instead of a model, a renderer in `brdffit.export.FIT_TARGETS` (``"gltf"``, ``"mitsuba"``): fit
            the models it represents exactly with every parameter in its ranges (`brdffit.export.Target.renders`)
            and return the one `brdffit.select` chooses among them (its own model alone where it has one).

    Returns:
        A `FitResult`.
    """
    if target is not None:
        return _fit_for_target(measurements, model, target, locals())
    if model is None:
        raise TypeError("fit needs a model spec (or a target renderer)")
    if channel_mode not in CHANNEL_MODES:
        raise ValueError(f"channel_mode must be one of {', '.join(CHANNEL_MODES)}, got {channel_mode!r}")
    options = dict(loss=loss, solver=solver, init=init, fixed=fixed, free=free, multistart=multistart,
                   robust=robust, max_steps=max_steps, rtol=rtol, atol=atol, seed=seed, coarse=coarse,
                   lobe_search=lobe_search)
    spec = model.spec if isinstance(model, Model) else model
    bar = Progress(f"fit {spec}", 4, enabled=progress, unit="stages")
    if channel_mode == "independent":
        result = _fit_independent(measurements, model, options, bar)
    else:
        result = _pipeline([measurements], model, bar=bar, **options)[0]
    bar.close(f"{result.status}, cost {result.cost:.6g}")
    if strict and not result.converged:
        raise FitError(f"fit of {result.spec} did not converge: {result.status}", result)
    return result


def _fit_for_target(measurements, model, target: str, arguments: dict) -> FitResult:
    """`fit` with a ``target``: its one model fitted, or `brdffit.select`'s choice among its models."""
    from ..select import target_models, select

    if model not in (None, "auto"):
        raise ValueError(f"target={target!r} chooses the model among those {target} represents exactly; give no "
                         f"model (got {model!r})")
    renders = target_models(target, None)
    options = {k: arguments[k] for k in ("loss", "solver", "fixed", "free", "max_steps", "rtol", "atol", "seed")}
    if len(renders) == 1:
        options.update({k: arguments[k] for k in ("init", "multistart", "channel_mode", "robust", "coarse",
                                                  "lobe_search", "strict", "progress")})
        return fit(measurements, renders[0], **options)
    return select(measurements, (), target=target, progress=arguments["progress"], **options).result


def _fit_independent(measurements, model, options: dict, bar: Progress) -> FitResult:
    """One fit per channel, solved as one batch of single-channel materials, assembled: shape parameters become
    per-channel arrays."""
    channels = measurements.n_channels
    base = _resolve_model(model, channels)
    single = get_model(base.spec, channels=1, **{
        name: (value[:1] if spec.colour else value) for (name, value), spec in zip(base.params.items(),
                                                                                   base.param_specs)})
    per_channel = [measurements.select_channels([c]) for c in range(channels)]
    if isinstance(options["init"], (dict, Model)):
        raise ValueError("channel_mode='independent' takes init='auto', 'model' or a list of candidates")
    results = _pipeline(per_channel, single, bar=bar, **options)

    def merge(attr):
        merged = {}
        for name, spec in zip(base.params, base.param_specs):
            parts = [np.atleast_1d(np.asarray(getattr(r, attr)[name])) for r in results]
            merged[name] = np.concatenate(parts) if spec.colour else np.stack([p[0] for p in parts])
        return merged

    worst = Status.worst(r.status for r in results)
    k = sum(r.n_params for r in results)
    n = sum(r.n_samples for r in results)
    cost = sum(r.cost for r in results)
    aic, bic = information_criteria(results[0].loss, cost, n, k)
    labels = [f"{label}@{c}" for c, r in enumerate(results) for label in r.labels]
    size = len(labels)
    cov, cor = np.zeros((size, size)), np.zeros((size, size))
    offset = 0
    for r in results:
        s = len(r.labels)
        cov[offset:offset + s, offset:offset + s] = r.covariance
        cor[offset:offset + s, offset:offset + s] = r.correlation
        offset += s
    return FitResult(
        model=None, params=merge("params"), stderr=merge("stderr"), stderr_robust=merge("stderr_robust"),
        stderr_laplace=merge("stderr_laplace"), noise_model=noise.merge([r.noise_model for r in results]),
        theta_i_max=max(r.theta_i_max for r in results), covariance=cov, correlation=cor,
        labels=labels, metrics={m: np.concatenate([r.metrics[m] for r in results]) for m in results[0].metrics},
        n_samples=n, n_params=k, dof=n - k, cost=cost, aic=aic, bic=bic, status=worst,
        bounds_hit=[f"{b}@{c}" for c, r in enumerate(results) for b in r.bounds_hit],
        warnings=[f"channel {c}: {w}" for c, r in enumerate(results) for w in r.warnings],
        steps=max(r.steps for r in results), compile_time=results[0].compile_time,
        run_time=sum(r.run_time for r in results), init_time=sum(r.init_time for r in results),
        loss=results[0].loss, solver=results[0].solver, channel_mode="independent", fixed=results[0].fixed,
        starts=[s for r in results for s in r.starts],
        noise_variance=float(np.mean([r.noise_variance for r in results])),
        strategy=results[0].strategy, models=[r.model for r in results],
    )


@one_blas_thread()
def fit_many(measurements_list, model, *, loss: str = FIT.loss, solver=FIT.solver, init="auto", fixed=None,
             free=None, robust=None, max_steps: int = FIT.max_steps, rtol: float = FIT.rtol, atol: float = FIT.atol,
             seed: int = FIT.seed, lobe_search: bool = True) -> list[FitResult]:
    """Fit one model to many equally shaped data sets: the pipeline of `fit`, every stage batched.

    This is the path for databases and spatially varying materials: every data set must have the same number of
    samples and channels (missing samples may differ). Each gets its own search; the solves run together, so one
    compiled program serves them all.

    Arguments:
        measurements_list: a sequence of `brdffit.Measurements` of equal shape.
        model, loss, solver, init, fixed, free, robust, max_steps, rtol, atol, seed, lobe_search: as for `fit`.

    Returns:
        One `FitResult` per data set, in order; each has the same answer as `fit` on that data set alone.

    The batch is padded with copies of its last data set up to `batch_bucket` of its size, whose results are
    dropped: each batch size compiles its own programs (1.7 s for Lambert + GGX), and a database's batches come in
    sizes that differ by one.
    """
    items = list(measurements_list)
    if not items:
        raise ValueError("fit_many needs at least one data set")
    shape = np.shape(items[0].values)
    for i, m in enumerate(items):
        if np.shape(m.values) != shape:
            raise ValueError(f"fit_many needs equally shaped data sets: item 0 has values of shape {shape}, "
                             f"item {i} has {np.shape(m.values)}; fit them separately with fit()")
    padded = items + [items[-1]] * (batch_bucket(len(items)) - len(items))
    return _pipeline(padded, model, loss=loss, solver=solver, init=init, fixed=fixed, free=free, multistart=0,
                     robust=robust, max_steps=max_steps, rtol=rtol, atol=atol, seed=seed, coarse="auto",
                     lobe_search=lobe_search, bar=Progress("fit_many", 4, enabled=False, unit="stages"))[:len(items)]


def batch_bucket(count: int) -> int:
    """The number of materials that `fit_many` fits for ``count`` of them: ``count`` up to 8, then the next of
    four sizes an octave (10, 12, 14, 16, 20, 24, 28, 32, 40, ...): at most a quarter of the work added, and a few
    compiled batch sizes for any count (the batches of a database of 1,000 materials cut for two workers hold 31
    and 32 materials; each size compiles its programs anew in every worker)."""
    if count <= 8:
        return count
    step = 1 << (count.bit_length() - 3)
    return -(-count // step) * step
