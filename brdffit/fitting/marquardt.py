r"""The default solver (``"lm"``): Levenberg-Marquardt on the separable problem's normal equations, stepped on the
host over compiled passes, for a whole batch of points at once.

Each step of every point (materials × starts; in a batch of several materials only the points still moving,
gathered, `_COMPACT_POINTS`) is one compiled pass over the data
(`brdffit.fitting.normal_equations.accumulate`, or in such a batch `brdffit.fitting.moments` where it applies):
JᵀJ, Jᵀr and the cost at the point, J in the physical free parameters. Because the residuals are affine in the
amplitudes, those sums give the cost as a function of the amplitudes exactly: each pass first moves the amplitudes
to their bounded optimum for the current outer parameters (the projection of `brdffit.fitting.separable`, here
from the pass's own sums: cost(a') = cost + 2 gᵀΔ + Δᵀ G Δ, Δ = a' − a, with the same exact active-set solve; no
move where rounding may have spoilt that prediction, `_TRUSTED_SPREAD`, so that every cost the solver compares is
measured or exactly predicted; and, for a kept trial, a second pass at the moved point where Δ jumped off a bound or
beyond the amplitude's own size or changed the cost by more than `_TRUSTED_CHANGE`, so that the outer tangents are
those of the projected point), then takes a Levenberg-Marquardt step

    (JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr        (Marquardt 1963, Eq. 29's scaling)

over the outer parameters, in their unconstrained variables (`brdffit.params`; the chain rule maps their columns),
and the amplitudes off their bounds: Kaufman's joint step (BIT 15, 1975). JᵀJ is the Hessian of the cost (over 2)
only where the residuals are small: a misspecified model, the rule on real measurements, leaves a second term
S = Σ rᵢ∇²rᵢ that Gauss-Newton ignores, and then converges linearly, in steps that alternate or creep (Lambert + three
Lafortune lobes refitted to a real paper from its screening fit: 70 steps). Each point therefore also carries a
structured secant approximation of S (Dennis, Gay & Welsch 1981, ACM TOMS 7(3), the NL2SOL algorithm: `_secant`) and
steps with JᵀJ + S in place of JᵀJ where S predicted its last trial's cost change better than Gauss-Newton did and
JᵀJ + S is positive definite (NL2SOL's choice between its two models): the same refit takes 18 steps, a selection
3-33 % fewer passes. A step is accepted only if the projected cost does not increase (at a kept trial's second pass
too); λ then shrinks tenfold if the step achieved at least `GAIN_RATIO` of the decrease its model predicted and stays
otherwise (Moré 1978), and a rejected step grows it tenfold. A point has converged when its next step and its
amplitude change are below ``rtol·|x| + atol`` (optimistix's Cauchy test on the variables) with λ ≤ 1, so that
damping cannot fake a small step, or with its last trial changing the cost by at most ``rtol·cost + atol`` (the
Cauchy test on the cost: at the optimum, rounding rejects every trial and λ grows). It stops at ``max_steps``, or
when λ exceeds 1e12 (no step of any length lowers the cost: a kink, or the optimum itself); the pipeline's
Karush-Kuhn-Tucker test (`brdffit.fitting.status`) then tells a stall from an optimum. A problem without outer
parameters (Lambert) converges after one projection. Parameters the pipeline holds (on a bound, or where a dead lobe
left them) simply do not move.

The transforms of `brdffit.params` reach a bound only where their slope is 0, so an outer scalar whose optimum lies
on a bound walks towards it in ever shorter steps, and its flat direction then keeps λ climbing to `MAX_DAMPING`
(Lambert + two Lafortune lobes on a real paper: 20 steps to reach cxy = −2, 25 more to stop). The solver therefore
keeps an ε-active set (Bertsekas 1982, SIAM J. Control Optim. 20(2), §3): a scalar within `BOUND_FRACTION` of a bound
whose descent direction −∂cost/∂p points out of the box is put on the bound in the next trial (a point that would
stop there tries the bound first) and held there once a trial with it is accepted. A scalar so held whose descent
direction points into the box (Karush-Kuhn-Tucker) is released, at convergence or as soon as moving it alone would
gain more than the step of the others (`PROPORTIONING`), and the point goes on; a released scalar, or one whose move
onto the bound a trial rejected with λ ≥ `SNAP_BLAME` (the other scalars' steps then too short to be blamed), is left
to the transforms for the rest of the solve (no cycling). A move onto a bound that leaves another free scalar without
any effect (its column of J vanishes: a layer's weight at 0 silences the layer's roughness, a Lafortune exponent at 0
its axis) is not taken, whatever its cost: on the bound that scalar could never move again, and the pair would stop
where the silenced one happened to be (Mitsuba's principled on a PTFE sample: the clearcoat put on 0 with its gloss
at 0.84, 45 % above the optimum the clearcoat reaches with the gloss at 0). Such a scalar is left to the transforms,
and the pipeline's hold rounds put it on its bound once the others have settled.

Why the engine has its own solver: its only compiled program is the pass, one per model structure and data
shape (a straight-line program of the residuals and Q tangents), which the polish, the full-data refinement and
the covariance share. An optimistix solve compiles the whole iteration (the solver's loop, its linear solves and
the transposed tangents of the projection) for each model and option, a far larger program than the pass
(docs/benchmarks.md). The optimistix solvers stay available by name
(`brdffit.fitting.solvers.SOLVERS`) and as objects, and `tests/test_marquardt.py` checks that both reach the
same optimum.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ..defaults import FIT
from ..params import bound_margin
from .moments import applies, moment_sums
from .normal_equations import (NormalEquations, accumulate, meat_of, metric_sums_of, noise_grams_of, pass_pieces,
                               timed)
from .outcome import SolveOutcome
from .problem import FitData, Problem
from .search import POLISH_STARTS
from .separable import solve_box

__all__ = ["Marquardt", "solve", "answer", "MAX_DAMPING", "RELATIVE_OFFSET", "EXACT_MOVE", "BEST_TIE", "GAIN_RATIO",
           "BOUND_FRACTION", "SNAP_BLAME", "PROPORTIONING"]

# A start that converged within this fraction of the lowest cost of its material's polish is as good an answer
# as the lowest (the pipeline keeps it rather than one that ran out of steps, `brdffit.fitting.api._best`).
BEST_TIE = 1e-6
# λ beyond which a point is stuck: no step, however short, lowers its cost (a kink, or rounding at the optimum
# of a loose problem); it ends there and the diagnosis decides between stalled and converged.
MAX_DAMPING = 1e12
_MIN_DAMPING = 1e-12
# A kept step that achieved less than this fraction of the decrease its Gauss-Newton model predicted keeps λ
# instead of shrinking it (Moré 1978's gain ratio; Nielsen 1999 and MINPACK's lmder use 1/4 too): where the
# model overshoots (the true Hessian along a direction twice JᵀJ, as between two near-identical Lafortune lobes),
# shrinking λ after every step that does not raise the cost made the steps alternate in sign for a thousand
# steps.
GAIN_RATIO = 0.25
# An outer scalar within this fraction of its scale (`brdffit.params.bound_margin`) of a bound, with its descent
# direction pointing out of the box, is put on the bound (the module doc's ε-active set; the pipeline's hold stage
# uses the same margin).
BOUND_FRACTION = 1e-3
# A scalar that the solve put on a bound, with its descent direction pointing back into the box, is released
# before the point converges where moving it alone would lower the cost (g_j² / (JᵀJ)_jj, the quadratic model's)
# by more than this many times the Gauss-Newton decrement gᵀ(JᵀJ)⁻¹g of the scalars that move: Dostál's
# proportioning (SIAM J. Optim. 7(3), 1997), which leaves a face of the box as soon as its own progress is the
# smaller one. Releasing only at convergence held pbrt's coated diffuse on clay on a face where the steps changed
# the cost by 1e-7 of itself for 35 steps before the release took it from 2.76 to 1.80.
PROPORTIONING = 1.0
# The λ from which a rejected trial that put scalars on their bounds bars them from the ε-active set for the rest of
# the solve (the module doc): the other scalars' steps are then a thousandth of their Gauss-Newton length or less,
# so the rejection is the bound's own. At smaller λ a rejection is mostly the others' steps; barring there left a
# Lafortune lobe's cxy creeping to −2 through its transform for 20 more steps, and, with the secant term, 119
# (Lambert + two Lafortune lobes on a real paper).
SNAP_BLAME = 1e3
# A projection that jumps an amplitude (off a bound, or by more than its value) by more than this fraction of the
# new value is followed by a pass at the moved point (`_Batch.refresh`).
_REPASS = 1e-3
# The least eigenvalue of the Jacobi-scaled JᵀJ + S (unit diagonal for JᵀJ) for the secant term S to be used in a
# step (`_step`): an S that makes the model indefinite, or nearly so, would step along a direction of negative
# curvature that only the damping bounds.
_SECANT_DEFINITE = 1e-8
# Bates & Watts (1981)'s relative offset convergence criterion: the Gauss-Newton step's reach in the tangent
# plane against the residual's size, √(gᵀ(JᵀJ)⁻¹g / p) / √(rᵀr / (n − p)). Below 1e-3 (their suggestion; R's
# nls tests the same ratio) the remaining step is about 1e-3 √p standard errors long and the cost within
# ~1e-6 p/n of its minimum. Misspecified multi-lobe fits otherwise walked flat valleys for dozens of steps that
# changed the cost by 1e-13 of itself (Lambert + 2 Lafortune lobes on 20,000 samples: 61 steps, now 26).
RELATIVE_OFFSET = 1e-3

# The last projection's move of the amplitudes (relative) within which the solver's sums stand for those of its
# answer: JᵀJ's outer columns scale with the amplitudes, so they are then exact to this relative order, and the
# cost is exact (quadratic in the amplitudes).
EXACT_MOVE = 1e-6

# A projection's predicted cost c + 2gᵀΔ + ΔᵀGΔ (g = Jᵀr and G = JᵀJ of the amplitudes) is exact in exact
# arithmetic, where its terms are bounded by the cost: the quadratic is a sum of squares, nonnegative along the whole
# line through Δ, so (gᵀΔ)² <= c ΔᵀGΔ, and as the projection does not raise the cost, |2gᵀΔ| + ΔᵀGΔ <= 9c. Its
# rounding is of the order of 1e-16 N times the magnitude of its products, at most 2|g|ᵀ|Δ| + (Σ √G_kk |Δ_k|)²
# (the spread). Where the spread exceeds this many times the smaller of the pass's own cost and the predicted one,
# the prediction is not trusted: the point is not moved and keeps the cost its pass measured (`_Batch._project`). A
# lobe whose Gram matrix is near 0 can jump to 1e53 with a predicted cost that rounding made meaningless (Lambert + 3
# Lafortune lobes on Ward data, 2,000 half-difference samples: the solve "converged" at a cost of 3.2 that was
# 1.8e108, and the fit ended there; a second pass at the moved point predicted 3.4 from a cost of 5e75 again). The
# predicted cost is the one compared, so the spread is measured against it too: a trial whose pass cost 2.5e29 (a
# Lafortune lobe of exponent 1.7e5 on a sample at its peak) with a spread of 7.6e29, 3 times that cost, predicted by
# cancellation a cost below 0 (clipped to 0) where the moved point costs 70, and the step was taken from a cost of
# 39.9 (Lambert + 2 Lafortune lobes on anisotropic GGX data, 500 samples).
_TRUSTED_SPREAD = 1e6
# A projection that changed the cost by more than this fraction, or that jumped an amplitude (`_REPASS`), has made
# the outer parameters' tangents stale: an accepted trial is passed over again (`_Batch.refresh`).
_TRUSTED_CHANGE = 0.1


@dataclasses.dataclass(frozen=True)
class Marquardt:
    """The engine's Levenberg-Marquardt (solver name ``"lm"``, `brdffit.fitting.solvers.SOLVERS`).

    Attributes:
        rtol, atol: the step test's tolerances (see the module doc).
        damping: the initial λ, relative to diag(JᵀJ) (Marquardt's 1e-3; the full-data refinement, which starts
            next to the optimum, uses 1e-6).
        offset: the relative offset below which a point has converged (Bates & Watts 1981; 0 turns the test off).
    """

    rtol: float = FIT.rtol
    atol: float = FIT.atol
    damping: float = 1e-3
    offset: float = RELATIVE_OFFSET

    def solve_starts(self, problem: Problem, starts: list[list[dict]], data: FitData, *, held=None,
                     metrics: bool = False, max_steps: int | None = None):
        """The engine's solver interface (`brdffit.fitting.solvers.BatchSolver`): `solve` of every start of
        every material, the starts padded to `polish_width` (repeating the last) so that one compiled pass serves
        a search's starts, a given start and the hold rounds alike.

        Returns:
            ``(outcomes, compile_seconds, run_seconds)``: for each material one `SolveOutcome` a start.
        """
        count = len(starts[0])
        width = polish_width(count, int(np.shape(data.values)[1]))
        padded = [material + [material[-1]] * (width - count) for material in starts]
        out, compile_time, run_time = timed(lambda: solve(
            problem, padded, [data], rtol=self.rtol, atol=self.atol,
            max_steps=problem.max_steps if max_steps is None else max_steps, damping=self.damping,
            offset=self.offset, held=held, metrics=metrics))
        return [material[:count] for material in out], compile_time, run_time


# A single start on this many samples or more is solved alone, not padded to POLISH_STARTS (`polish_width`). A
# selection screens on a subsample of 4,096 rows from twice that many on (`brdffit.select.SCREEN_SAMPLES`); below,
# its refits run on the screen's own data shape and share its padded programs. Alone, a start on up to four times
# the screen's rows runs on slices of them (`brdffit.fitting.normal_equations.SLOTS`), the screen's program where
# the slices are as long as the screen's rows.
SINGLE_START_SAMPLES = 8192


def polish_width(count: int, samples: int) -> int:
    """The number of points a solve of ``count`` starts on ``samples`` samples runs: the next multiple of
    `POLISH_STARTS` (one compiled pass for a search's starts, a given start and the hold rounds), but a single
    start on `SINGLE_START_SAMPLES` or more samples alone: there every padding copy costs a pass over the data at
    each step (its pass then runs on slices of the samples, `brdffit.fitting.normal_equations.SLOTS`)."""
    if count == 1 and samples >= SINGLE_START_SAMPLES:
        return 1
    return -(-count // POLISH_STARTS) * POLISH_STARTS


# A batch of several materials with more points than this is compacted: each pass evaluates only the points still
# moving (`_Batch._pass`), gathered into a batch of `_width` points. A `fit_many` batch is otherwise passed over
# whole until its slowest point converges (32 materials x 4 starts of Lambert + GGX: most points converge in 4-5
# steps, the slowest in 12).
_COMPACT_POINTS = 8
# The most points of one compact pass: a wider one runs in groups, faster on a CPU than in one pass, whose
# intermediates would leave the cache.
_MAX_WIDTH = 32


def _width(count: int, total: int) -> int:
    """The width of a compact pass over ``count`` of a batch's ``total`` points: the least power of two at least
    ``count`` and `_COMPACT_POINTS`, or ``total`` below that (a few compiled widths serve every pass)."""
    width = _COMPACT_POINTS
    while width < count:
        width *= 2
    return min(width, total)


def answer(costs, ran_out) -> int:
    """The answer among one material's points: the lowest finite cost, or the lowest of the points that did not
    run out of steps within `BEST_TIE` of it (to the solver's tolerance the same optimum, and only a converged
    point shows it).

    Arguments:
        costs: ``(S,)`` the points' costs (NaN or inf where not finite).
        ran_out: ``(S,)`` True where a point ended at its step limit.

    Returns:
        The index of the answer.
    """
    costs = np.where(np.isfinite(costs), costs, np.inf)
    lowest = int(np.argmin(costs))
    if not np.isfinite(costs[lowest]):
        return 0
    tied = np.flatnonzero(~np.asarray(ran_out) & (costs <= costs[lowest] + BEST_TIE * abs(costs[lowest])))
    return int(tied[np.argmin(costs[tied])]) if tied.size else lowest


def _scatter(sums: NormalEquations, chosen, shape: tuple, base: NormalEquations | None) -> NormalEquations:
    """Sums of the flat points ``chosen`` of a ``shape`` (M, S) batch, placed among ``base``'s sums of the other
    points (NaN where ``base`` or its field is None)."""
    fields = []
    for part, full in zip(sums, base if base is not None else [None] * len(sums)):
        if part is None:
            fields.append(None)
            continue
        tail = np.shape(part)[1:]
        out = np.full((int(np.prod(shape)),) + tail, np.nan) if full is None else \
            np.array(full, dtype=float).reshape((-1,) + tail)
        out[chosen] = part
        fields.append(out.reshape(tuple(shape) + tail))
    return NormalEquations(*fields)


class _State:
    """The batch's current points: physical values ``x (M, S, P)`` with their amplitudes projected, the pass's
    sums moved with them (see the module doc), and, when the solve keeps them, the pass's arrays of each piece
    at the evaluated point, before the projection moved ``x`` by ``delta`` (`_point_arrays`: each point's own
    arrays, referenced, so that choosing between two states copies no array);
    ``spread`` ``(M, S)`` is the magnitude of the terms of the projection's predicted cost change (`_TRUSTED_SPREAD`,
    0 where it did not move)."""

    def __init__(self, x, sums: NormalEquations, delta, evaluated=None, values=None, spread=None, transformed=None):
        self.x, self.sums, self.delta, self.values = x, sums, delta, values
        self.evaluated = sums.cost if evaluated is None else evaluated  # the pass's own cost, before projecting
        self.spread = np.zeros(np.shape(sums.cost)) if spread is None else spread
        self.transformed = transformed  # (u, dp/du) of ``x``, once `_Batch.transformed` has computed them

    def where(self, take, other: "_State") -> "_State":
        """This state where ``take (M, S)`` is True, ``other`` elsewhere."""
        def pick(a, b):
            if a is None:  # sums that were not asked for
                return None
            return np.where(np.reshape(take, take.shape + (1,) * (np.ndim(a) - take.ndim)), a, b)

        if self.values is None or take.all():
            values = self.values
        elif not take.any():
            values = other.values
        else:
            values = [(np.where(take, a, c), np.where(take, f, g)) for (a, f), (c, g) in zip(self.values, other.values)]
        transformed = None
        if self.transformed is not None and other.transformed is not None:
            transformed = tuple(pick(a, b) for a, b in zip(self.transformed, other.transformed))
        return _State(pick(self.x, other.x), NormalEquations(*(pick(a, b) for a, b in zip(self.sums, other.sums))),
                      pick(self.delta, other.delta), pick(self.evaluated, other.evaluated), values,
                      pick(self.spread, other.spread), transformed)


def _point_arrays(kept: list) -> list:
    """A pass's arrays of each piece (`accumulate` with ``values=True``: tangents and residuals ``(M, S, C, Q + 1,
    N)`` and model values ``(M, S, N, C)``) as ``(M, S)`` object arrays of each point's own arrays (views, on the
    host, where the meat and the metric sums of the kept values are formed): `_State.where` then picks a point's
    arrays without copying them, at every step of a solve that keeps them."""
    out = []
    for a, f in kept:
        f = np.asarray(f)
        tangents, values = np.empty(a.shape[:2], object), np.empty(f.shape[:2], object)
        for m, s in np.ndindex(a.shape[:2]):
            tangents[m, s], values[m, s] = a[m, s], f[m, s]
        out.append((tangents, values))
    return out


class _Batch:
    """The flat layout of a problem's free parameters and the passes over a batch's data."""

    def __init__(self, problem: Problem, pieces: list[FitData], keep: bool = False, compact: bool = False):
        layout = problem.layout
        self.problem, self.pieces, self.layout, self.keep = problem, pieces, layout, keep
        free = problem.free
        self.offsets = layout.offsets(free)
        self.lower = np.concatenate([np.full(layout[n].size, layout[n].spec.lower) for n in free])
        self.upper = np.concatenate([np.full(layout[n].size, layout[n].spec.upper) for n in free])
        self.size = self.lower.size
        self.is_outer = np.zeros(self.size, bool)
        self.margin = np.zeros(self.size)  # the outer scalars' `BOUND_FRACTION` margins
        for name in problem.outer:
            self.is_outer[self.offsets[name]] = True
            self.margin[self.offsets[name]] = bound_margin(layout[name].spec, BOUND_FRACTION)
        linear = problem.linear
        # (C, K): the flat index of amplitude k in channel c.
        self.amplitudes = np.array([[self.offsets[n].start + c for n in linear] for c in range(problem.channels)],
                                   dtype=int).reshape(problem.channels, len(linear))
        self.is_amplitude = np.zeros(self.size, bool)
        self.is_amplitude[self.amplitudes.ravel()] = True
        # (M,) valid residuals, counted on the host (a compiled count would add its compilation to a first fit)
        self.n_values = sum(np.sum(np.asarray(piece.mask), axis=(1, 2)) for piece in pieces)
        self.compact = compact
        # A compact batch's passes form their sums from the channels' shared moments where they can
        # (`brdffit.fitting.moments`), but for the answers' sums with the meat and the metric sums (`accumulate`).
        self.moments = compact and applies(problem, {k: np.asarray(v) for k, v in pieces[0].fixed.items()})

    def trees(self, x) -> dict:
        batch = x.shape[:2]
        return {n: np.reshape(x[..., self.offsets[n]], batch + self.layout[n].shape) for n in self.problem.free}

    def evaluate(self, x, base: "_State | None" = None, points=None, refresh: bool = True) -> _State:
        """A pass at ``x`` with the amplitudes then moved to their optimum. The sums predict the cost at the moved
        amplitudes exactly in exact arithmetic; where rounding may have made that prediction meaningless (a lobe
        that sees almost no sample has a Gram matrix near 0, whose solve can jump to 1e118: `_TRUSTED_SPREAD`), the
        point is not moved and keeps the cost its pass measured (`_project`). With ``refresh``, a second pass
        evaluates every point whose tangents the move made stale (`refresh`); the solver asks for that only for
        the trials it accepts, since a rejected trial's tangents are never used (a sizeable share of those second
        passes of a Lambert + GGX `fit_many`). Each point's second pass is its own: whether one point is evaluated
        again never changes another's path (a fit's answer does not depend on the other starts and materials of its
        batch).

        Arguments:
            x: physical values ``(M, S, P)``.
            base: the state whose points stand where ``points`` is False (required with ``points``).
            points: ``(M, S)`` the points to evaluate (default: all).
            refresh: also pass again over the points that `refresh` would.

        Returns:
            The `_State` of every point.
        """
        if points is None:
            points = np.ones(x.shape[:2], bool)
        state = self._project(x, base, points)
        return self.refresh(state, points) if refresh else state

    def refresh(self, state: _State, points) -> _State:
        """``state`` with a second pass at those of ``points`` whose projection moved an amplitude off a bound or
        by more than its own value (and by more than `_REPASS` of the result), or changed the cost by more than
        `_TRUSTED_CHANGE`: the tangents of the outer parameters are those before the move, and a lobe whose
        amplitudes were clipped to 0 has none at all, so that its shape could never move again. Smaller moves
        keep the slightly older tangents, which the damped step absorbs (one pass a step)."""
        again = points & self._stale(state)
        return self._project(state.x, state, again) if again.any() else state

    def _stale(self, state: _State):
        """``(M, S)``: where `refresh` passes again."""
        x = state.x - state.delta  # the evaluated point
        jump = (x <= self.lower) | (x >= self.upper) | (np.abs(state.delta) > np.abs(x))
        moved = np.any(jump & (np.abs(state.delta) > _REPASS * np.abs(state.x) + 1e-300), axis=-1)
        with np.errstate(invalid="ignore"):
            return moved | (np.abs(state.sums.cost - state.evaluated) > _TRUSTED_CHANGE * np.abs(state.evaluated))

    def _project(self, x, base: "_State | None", points) -> _State:
        """`_pass` at the selected ``points`` of ``x``, each followed by its projection, but for a point whose
        projection's prediction rounding may have spoilt (`_TRUSTED_SPREAD`): that point stays where the pass
        evaluated it, with the pass's own sums, whose cost is measured. The other points are ``base``'s."""
        sums, values = self._pass(x, base, points)
        state = self._projected(x, sums, values)
        with np.errstate(invalid="ignore"):  # a point whose pass was not finite has nothing to project
            scale = np.minimum(np.abs(state.evaluated), state.sums.cost)
            untrusted = np.isfinite(state.evaluated) & ~(state.spread <= _TRUSTED_SPREAD * scale)
        if untrusted.any():
            state = _State(x, sums, np.zeros(x.shape), values=values).where(untrusted, state)
        return state if base is None or points.all() else state.where(points, base)

    def _pass(self, x, base: "_State | None", points):
        """The pass's sums (and, when the solve keeps them, arrays) at the ``points`` of ``x``: over the whole
        ``(M, S)`` batch, or, for a compact batch, over only the selected points, gathered into a batch of
        `_width` points each with its own material's data (the rest of the result is copied from ``base``)."""
        if not self.compact:
            # A solve that keeps its passes' arrays forms the meat of its answer only (`solve`).
            out = accumulate(self.problem, self.trees(x), self.pieces, values=self.keep, meat=not self.keep)
            return (out[0], _point_arrays(out[1])) if self.keep else (out, None)
        chosen = np.flatnonzero(points.ravel())
        return _scatter(self.gathered_sums(x, chosen), chosen, points.shape, base.sums if base is not None else None), \
            None

    def gathered_sums(self, x, chosen, metrics: bool = False) -> NormalEquations:
        """The sums at the points ``chosen`` (flat indices into the ``(M, S)`` batch of ``x``), each with its own
        material's data, in gathered batches of at most `_MAX_WIDTH` points: fields with a leading axis of
        ``len(chosen)``; the meat and the metric sums only with ``metrics``."""
        count = x.shape[1]
        flat = x.reshape((-1, 1) + x.shape[2:])
        groups = []
        for start in range(0, chosen.size, _MAX_WIDTH):
            group = chosen[start:start + _MAX_WIDTH]
            width = _width(group.size, x.shape[0] * count)
            padded = np.concatenate([group, np.full(width - group.size, group[-1])])
            if self.moments and not metrics:
                sums = moment_sums(self.problem, self.trees(flat[padded]), self.pieces, padded // count)
            else:
                sums = accumulate(self.problem, self.trees(flat[padded]), self.pieces, metrics=metrics,
                                  meat=metrics, materials=padded // count)
            groups.append([None if a is None else np.reshape(a, (width,) + np.shape(a)[2:])[:group.size]
                           for a in sums])
        return NormalEquations(*(None if parts[0] is None else np.concatenate(parts) for parts in zip(*groups)))

    def _projected(self, x, sums: NormalEquations, values) -> _State:
        delta = np.zeros(x.shape)
        if not self.amplitudes.size:
            return _State(x, sums, delta, values=values)
        index = self.amplitudes
        jtj, jtr = sums.jtj, sums.jtr
        with np.errstate(invalid="ignore", over="ignore"):
            gram = jtj[..., index[:, :, None], index[:, None, :]]  # (M, S, C, K, K)
            gradient = jtr[..., index]  # (M, S, C, K)
            a = x[..., index]
            finite = np.all(np.isfinite(gram), axis=(-1, -2)) & np.all(np.isfinite(gradient), axis=-1)
            gram = np.where(finite[..., None, None], gram, np.eye(index.shape[1]))
            rhs = np.where(finite[..., None], np.einsum("...kl,...l->...k", gram, a) - gradient, a)
            best = solve_box(gram, rhs, self.lower[index[0]], self.upper[index[0]])
            best = np.where(finite[..., None], best, a)
            step = best - a
            change = 2.0 * np.sum(gradient * step, axis=-1) + np.einsum("...k,...kl,...l->...", step, gram, step)
            change = np.where(finite, change, 0.0)
            reach = np.sum(np.sqrt(np.abs(np.einsum("...kk->...k", gram))) * np.abs(step), axis=-1)
            spread = np.sum(np.where(finite, 2.0 * np.sum(np.abs(gradient * step), axis=-1) + reach * reach, 0.0),
                            axis=-1)
            x = x.copy()
            x[..., index] = best
            delta[..., index] = step
            channel_cost = np.maximum(sums.channel_cost + change, 0.0)
            moved = NormalEquations(jtj=jtj, jtr=jtr + np.einsum("...pq,...q->...p", jtj, delta),
                                    cost=np.where(np.isfinite(sums.cost), np.sum(channel_cost, axis=-1), sums.cost),
                                    meat=sums.meat, channel_cost=channel_cost, metric_sums=sums.metric_sums,
                                    noise_grams=sums.noise_grams)
        return _State(x, moved, delta, sums.cost, values, spread)

    def onto_bounds(self, state: _State, excluded):
        """The outer scalars to put on a bound (the module doc's ε-active set): within `margin` of a finite bound
        with −Jᵀr pointing out of the box, not in ``excluded`` ``(M, S, P)``.

        Returns:
            ``(snap, bound)``: ``(M, S, P)`` where to snap, and the bound each would go to.
        """
        x, gradient = state.x, state.sums.jtr
        with np.errstate(invalid="ignore"):
            low = (x - self.lower <= self.margin) & (gradient > 0)
            high = (self.upper - x <= self.margin) & (gradient < 0)
        return self.is_outer & (low | high) & ~excluded, np.where(low, self.lower, self.upper)

    def inward(self, state: _State):
        """``(M, S, P)``: scalars on a bound whose descent direction −Jᵀr points into the box."""
        x, gradient = state.x, state.sums.jtr
        return ((x <= self.lower) & (gradient < 0)) | ((x >= self.upper) & (gradient > 0))

    def unconstrained(self, x):
        """The outer scalars' unconstrained variables ``(M, S, P)`` (amplitude entries: the physical values)."""
        u = x.copy()
        for name in self.problem.outer:
            spec = self.layout[name].spec
            u[..., self.offsets[name]] = spec.to_unconstrained(x[..., self.offsets[name]], xp=np)
        return u

    def physical(self, u, x):
        """``x`` with its outer scalars replaced by those of the unconstrained ``u``."""
        out = x.copy()
        for name in self.problem.outer:
            spec = self.layout[name].spec
            out[..., self.offsets[name]] = spec.from_unconstrained(u[..., self.offsets[name]], xp=np)
        return out

    def slopes(self, u):
        """dp/du ``(M, S, P)``: the transforms' slopes on the outer scalars, 1 on the amplitudes."""
        out = np.ones(u.shape)
        for name in self.problem.outer:
            out[..., self.offsets[name]] = self.layout[name].spec.transform_slope(u[..., self.offsets[name]])
        return out

    def transformed(self, state: _State):
        """``(u, dp/du)`` of the state's points (`unconstrained`, `slopes`), computed once per state."""
        if state.transformed is None:
            u = self.unconstrained(state.x)
            state.transformed = (u, self.slopes(u))
        return state.transformed


class _Step(NamedTuple):
    """Every point's damped step (`_step`), each field ``(M, S)`` unless said.

    Fields:
        step: ``(M, S, P)``, the step in the unconstrained variables (0 where a scalar does not move: held, or an
            amplitude on its bound).
        u: ``(M, S, P)``, the unconstrained variables it starts from.
        offset: the relative offset (`RELATIVE_OFFSET`) over the scalars that move, Gauss-Newton's.
        predicted: the cost change that the model the step used predicts (the gain ratio's denominator).
        gauss_newton, with_secant: the cost change that Gauss-Newton's model, and that model with the secant term,
            predict for the step (NL2SOL's choice of the next step's model).
        decrement: Gauss-Newton's decrement gᵀ(JᵀJ)⁻¹g over the scalars that move (`PROPORTIONING`).
        Where a point's system is not finite, its offset and decrement are inf.
    """

    step: np.ndarray
    u: np.ndarray
    offset: np.ndarray
    predicted: np.ndarray
    gauss_newton: np.ndarray
    with_secant: np.ndarray
    decrement: np.ndarray


def _step(batch: _Batch, state: _State, damping, held, secant, augment) -> _Step:
    """The damped step of every point (`_Step`).

    Arguments:
        secant: ``(M, S, P, P)``, each point's secant term S in the unconstrained variables (`_secant`).
        augment: ``(M, S)``: the points whose step adds S to JᵀJ; a point whose JᵀJ + S is not positive definite
            (`_SECANT_DEFINITE`) steps by Gauss-Newton all the same.
    """
    x = state.x
    u, slope = batch.transformed(state)
    moving = batch.is_outer & ~held
    if batch.amplitudes.size:
        on_box = (x > batch.lower + 1e-12) & (x < batch.upper - 1e-12)
        moving = moving | (batch.is_amplitude & on_box)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        jtj = state.sums.jtj * slope[..., :, None] * slope[..., None, :]
        jtr = state.sums.jtr * slope
        # Jacobi scaling (diag(JᵀJ) as Marquardt's metric): the scaled system J̃ᵀJ̃ + λI is positive definite.
        scale = np.sqrt(np.maximum(np.einsum("...ii->...i", jtj), 1e-300))
        both = moving[..., :, None] & moving[..., None, :]
        eye = np.eye(batch.size)
        scaling = scale[..., :, None] * scale[..., None, :]
        augmented = np.where(both, (jtj + np.where(augment[..., None, None], secant, 0.0)) / scaling, eye)
        definite = np.all(np.isfinite(augmented), axis=(-1, -2))
        definite[definite] = np.linalg.eigvalsh(augmented[definite])[..., 0] > _SECANT_DEFINITE
        model = np.where(definite[..., None, None], augmented, np.where(both, jtj / scaling, eye))
        lhs = np.where(both, model + damping[..., None, None] * eye, eye)
        rhs = np.where(moving, -jtr / scale, 0.0)
        finite = np.all(np.isfinite(lhs), axis=(-1, -2)) & np.all(np.isfinite(rhs), axis=-1)
        lhs = np.where(finite[..., None, None], lhs, eye)
        rhs = np.where(finite[..., None], rhs, 0.0)
        step = np.linalg.solve(lhs, rhs[..., None])[..., 0] / scale
        # The undamped Gauss-Newton system (a ridge for the directions the data do not determine) for the offset,
        # which stays Bates & Watts's whichever model steps: the pipeline's status test is Gauss-Newton's too.
        gauss = np.where(both & finite[..., None, None], jtj / scaling + 1e-12 * eye, eye)
        decrement = np.sum(rhs * np.linalg.solve(gauss, rhs[..., None])[..., 0], axis=-1)
        p = np.sum(moving, axis=-1)
        offset = np.sqrt(decrement / np.maximum(p, 1)) / np.sqrt(state.sums.cost
                                                                  / np.maximum(batch.n_values[:, None] - p, 1))
        # The cost change the step's undamped model predicts: 2 gᵀδ + δᵀ JᵀJ δ (with S: δᵀ (JᵀJ + S) δ; the
        # gain ratio's denominator), in the scaled variables z = δ·scale where rhs = −g/scale.
        z = np.where(moving, step * scale, 0.0)
        predicted = -2.0 * np.sum(rhs * z, axis=-1) + np.einsum("...i,...ij,...j->...", z,
                                                                np.where(finite[..., None, None], model, eye), z)
        step = np.where(moving, step, 0.0)
        gauss_newton = 2.0 * np.sum(jtr * step, axis=-1) + np.einsum("...i,...ij,...j->...", step, jtj, step)
        with_secant = gauss_newton + np.einsum("...i,...ij,...j->...", step, secant, step)
    return _Step(step, u, np.where(finite & (p > 0), offset, np.inf), predicted, gauss_newton, with_secant,
                 np.where(finite, decrement, np.inf))


def _secant(batch: _Batch, old: _State, new: _State, accepted, secant, still):
    """The secant terms ``(M, S, P, P)`` after the step from ``old`` to ``new`` where ``accepted`` ``(M, S)``
    (elsewhere ``secant`` as it was): Dennis, Gay & Welsch's update (ACM TOMS 7(3), 1981: the NL2SOL algorithm)
    of S ≈ Σ rᵢ∇²rᵢ in the unconstrained variables, with their sizing factor τ = min(1, |sᵀy♯| / |sᵀSs|) applied
    first:

        S₊ = τS + (w yᵀ + y wᵀ) / (yᵀs) − (wᵀs) y yᵀ / (yᵀs)²,   w = y♯ − τS s,

    where s is the step (the scalars in ``still`` ``(M, S, P)``, which did not move by a step, excluded), y the
    change of Jᵀr and y♯ = y − J₊ᵀJ₊ s, so that J₊ᵀJ₊ + S₊ meets the secant equation (J₊ᵀJ₊ + S₊) s = y. A
    step with yᵀs ≤ 0 (no positive curvature along it) leaves S as it was."""
    (u0, slope0), (u1, slope1) = batch.transformed(old), batch.transformed(new)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        s = np.where(still, 0.0, u1 - u0)
        y = np.where(still, 0.0, new.sums.jtr * slope1 - old.sums.jtr * slope0)
        jtj = new.sums.jtj * slope1[..., :, None] * slope1[..., None, :]
        y_sharp = y - np.einsum("...ij,...j->...i", np.where(still[..., None, :], 0.0, jtj), s)
        ss = np.einsum("...ij,...j->...i", secant, s)
        sss = np.sum(s * ss, axis=-1)
        tau = np.where(np.abs(sss) > 0, np.minimum(1.0, np.abs(np.sum(s * y_sharp, axis=-1)) / np.abs(sss)), 1.0)
        w = y_sharp - tau[..., None] * ss
        ys = np.sum(y * s, axis=-1)
        ok = accepted & np.isfinite(ys) & (ys > 0)
        ys = np.where(ok, ys, 1.0)
        updated = tau[..., None, None] * secant \
            + (w[..., :, None] * y[..., None, :] + y[..., :, None] * w[..., None, :]) / ys[..., None, None] \
            - (np.sum(w * s, axis=-1) / ys ** 2)[..., None, None] * y[..., :, None] * y[..., None, :]
        ok &= np.all(np.isfinite(updated), axis=(-1, -2))
    return np.where(ok[..., None, None], updated, secant)


def _moved_little(state: _State, atol: float) -> np.ndarray:
    """``(M, S)``: the points whose last projection moved every amplitude by at most `EXACT_MOVE` of itself (+
    ``atol``), so that their sums stand for those of the points themselves."""
    return np.all(np.abs(state.delta) <= EXACT_MOVE * np.abs(state.x) + atol, axis=-1)


def silenced(jtj, trial_jtj) -> np.ndarray:
    """``(..., P)``: the free scalars that act on the residuals at the current point (a nonzero diagonal of JᵀJ) and
    not at all at the trial point (an exactly zero one), from the two points' ``JᵀJ`` ``(..., P, P)``."""
    now, then = np.diagonal(jtj, axis1=-2, axis2=-1), np.diagonal(trial_jtj, axis1=-2, axis2=-1)
    return (now > 0) & (then == 0)


def solve(problem: Problem, starts: list[list[dict]], pieces: list[FitData], *, rtol: float, atol: float,
          max_steps: int, damping: float = 1e-3, offset: float = RELATIVE_OFFSET,
          held: list[dict] | None = None, metrics: bool = False) -> list[list[dict]]:
    """Solve every start of every material (the module doc's iteration, all points together).

    Arguments:
        problem: the `Problem` (its `linear` amplitudes are projected at every pass, its `outer` ones stepped).
        starts: for each of M materials, S dicts of physical values of every parameter.
        pieces: the data of the M materials with a leading material axis, whole or in chunks
            (`brdffit.fitting.normal_equations.chunks`); ``fixed`` holds the values of the parameters that are not
            free.
        rtol, atol: the step test's tolerances.
        max_steps: the most steps (passes after the first) of each point.
        damping: the initial λ.
        offset: the relative offset test's tolerance (`RELATIVE_OFFSET`; 0: off).
        held: for each material, outer name -> physical value to hold (NaN: free), the same for each start.
        metrics: also give the metric sums of each returned point (`brdffit.metrics.metric_sums`), from the model
            values of the pass that evaluated it, which the solve keeps for its current points.

    Returns:
        For each material, a list of S `SolveOutcome`: ``params`` (physical, every parameter), ``cost``,
        ``steps``, ``max_steps`` (the step limit ended it), ``nonfinite``, ``normal`` (the `NormalEquations` at
        the returned point, in the physical free parameters; with ``metrics``, its metric sums) and ``exact``:
        the last pass evaluated the returned point itself, up to an amplitude move within `EXACT_MOVE` (its sums
        are then those of the point to that order, and no further pass at the answer is needed); ``answer``:
        the material's answer (`answer`, True for one point a material).
    """
    layout, free = problem.layout, problem.free
    materials, count = len(starts), len(starts[0])
    pieces = pass_pieces(pieces, (materials, count))  # every pass reads them
    compact = materials > 1 and materials * count > _COMPACT_POINTS
    batch = _Batch(problem, pieces, keep=metrics and not compact, compact=compact)
    x = np.stack([np.stack([layout.flatten(s, free) for s in material]) for material in starts]).astype(float)
    x = x.reshape(materials, count, batch.size)
    hold = np.zeros(x.shape, bool)
    for m, holds in enumerate(held or []):
        for name, value in holds.items():
            value = np.ravel(np.broadcast_to(np.asarray(value, dtype=float), layout[name].shape))
            mask = np.isfinite(value)
            hold[m, :, batch.offsets[name]] = mask
            x[m, :, batch.offsets[name]] = np.where(mask, value, x[m, :, batch.offsets[name]])
    state = batch.evaluate(x)
    on_bound = np.zeros(x.shape, bool)  # put on a bound by this solve (the module doc's ε-active set)
    barred = hold.copy()  # never put on a bound: held by the caller, released, or a rejected move
    lam = np.full(x.shape[:2], float(damping))
    secant = np.zeros(x.shape + x.shape[-1:])  # each point's S (the module doc), in the unconstrained variables
    augment = np.zeros(x.shape[:2], bool)  # S predicted the last trial's cost change better than Gauss-Newton
    steps = np.zeros(x.shape[:2], int)
    done = ~np.isfinite(state.sums.cost)
    converged = np.zeros(x.shape[:2], bool)
    change = np.full(x.shape[:2], np.inf)  # |Δcost| of each point's last trial
    while True:
        active = ~done & (steps < max_steps)
        if not active.any():
            break
        snap, bound = batch.onto_bounds(state, barred | on_bound)
        snap &= active[..., None]
        still = hold | on_bound | snap
        trial_step = _step(batch, state, lam, still, secant, augment)
        step, u, relative_offset, decrement = trial_step.step, trial_step.u, trial_step.offset, trial_step.decrement
        outer = batch.is_outer
        small = (np.linalg.norm(np.where(outer, step, 0.0), axis=-1)
                 <= rtol * np.linalg.norm(np.where(outer, u, 0.0), axis=-1) + atol)
        small &= np.linalg.norm(state.delta, axis=-1) <= rtol * np.linalg.norm(state.x, axis=-1) + atol
        # Damping cannot fake a small step: λ <= 1, or the last trial changed the cost by no more than the
        # tolerance (at the optimum rounding rejects every trial and λ grows).
        finished = active & ((small & ((lam <= 1.0) | (change <= rtol * np.abs(state.sums.cost) + atol)))
                             | (relative_offset <= offset))
        # A point that would stop next to a bound its descent direction points at first tries the bound.
        finished &= ~snap.any(axis=-1)
        # Karush-Kuhn-Tucker at a converged point: a scalar this solve put on a bound that the descent direction
        # would take back into the box is released, and the point steps on (from the next round, with it free).
        # Before convergence too where that scalar alone, moved into the box, would lower the cost more than the
        # Gauss-Newton step of the scalars that move can (`PROPORTIONING`).
        inward = on_bound & batch.inward(state)
        with np.errstate(invalid="ignore", divide="ignore"):
            gain = state.sums.jtr ** 2 / np.einsum("...ii->...i", state.sums.jtj)
        release = inward & (finished[..., None] | (active[..., None] & (gain > PROPORTIONING * decrement[..., None])))
        resumed = release.any(axis=-1)
        on_bound &= ~release
        barred |= release
        lam = np.where(resumed, damping, lam)
        finished &= ~resumed
        converged |= finished
        done |= finished
        active &= ~(finished | resumed)
        if not (active | resumed).any():
            break
        snap &= active[..., None]
        trial = batch.physical(u + step, state.x)
        trial = np.where(outer, trial, np.clip(state.x + step, batch.lower, batch.upper))
        trial = np.where(snap, bound, np.where(hold | on_bound, state.x, trial))
        trial = np.where(active[..., None], trial, state.x)
        candidate = batch.evaluate(trial, state, active, refresh=False)
        change = np.where(active, np.abs(candidate.sums.cost - state.sums.cost), change)
        steps += active
        # A move onto a bound that silences another free scalar is not taken (module doc), nor counted against λ.
        silencing = snap.any(axis=-1) & np.any(silenced(state.sums.jtj, candidate.sums.jtj) & ~snap & ~hold,
                                               axis=-1)
        better = (active & ~silencing & np.isfinite(candidate.sums.cost)
                  & (candidate.sums.cost <= state.sums.cost))
        # The second pass of a kept trial (`_Batch.refresh`) measures the moved point itself: where it costs more than
        # the current point after all, the trial is rejected, so that no step raises the cost.
        candidate = batch.refresh(candidate, better)
        better &= np.isfinite(candidate.sums.cost) & (candidate.sums.cost <= state.sums.cost)
        with np.errstate(invalid="ignore", divide="ignore"):
            poor = (candidate.sums.cost - state.sums.cost) / trial_step.predicted < GAIN_RATIO
        actual = candidate.sums.cost - state.sums.cost
        with np.errstate(invalid="ignore"):
            augment = np.where(active & np.isfinite(actual), np.abs(actual - trial_step.with_secant)
                               < np.abs(actual - trial_step.gauss_newton), augment)
        secant = _secant(batch, state, candidate, better, secant, still)
        state = candidate.where(better, state)
        on_bound |= snap & better[..., None]
        barred |= snap & ((active & ~better & (lam >= SNAP_BLAME)) | silencing)[..., None]
        lam = np.where(better, np.where(poor, lam, np.maximum(lam / 10.0, _MIN_DAMPING)),
                       np.where(active & ~silencing, lam * 10.0, lam))
        done |= active & (lam > MAX_DAMPING)
    # Each material's answer (`answer`): the point the pipeline keeps, marked so, since a further pass at it can
    # move its cost by rounding below or above another start's at the same optimum.
    ran_out = ~converged & (steps >= max_steps)
    chosen = np.array([m * count + answer(state.sums.cost[m], ran_out[m]) for m in range(materials)])
    answers = np.isin(np.arange(materials * count), chosen).reshape(x.shape[:2])
    if compact:
        # One pass at each material's answer gives its own sums, meat and metric sums: cheaper than carrying a
        # whole batch's arrays through every step. The other points keep their last sums, without the meat and
        # metrics.
        state.sums = _scatter(batch.gathered_sums(state.x, chosen, metrics=metrics), chosen, answers.shape,
                              state.sums)
        state.delta = np.where(answers[..., None], 0.0, state.delta)
    moved_little = _moved_little(state, atol)
    formed = answers & metrics  # the points whose meat and metric sums are formed; the others' are left None
    if metrics and not compact:
        # They serve an answer whose sums are its own (`exact` below; the pipeline passes again at any other,
        # `brdffit.fitting.api`), so they are formed at those answers alone.
        formed = answers & moved_little
        own = np.flatnonzero(formed.ravel())
        if own.size:
            material_of = own // count
            tangents = [np.stack(list(a.ravel()[own]))[:, None] for a, _ in state.values]
            values = [np.stack(list(f.ravel()[own]))[:, None] for _, f in state.values]
            parts = (meat_of(problem, tangents), metric_sums_of(values, pieces, materials=material_of),
                     noise_grams_of(problem, tangents, values, pieces, materials=material_of))
            meat, metric_sums, noise_grams = (np.reshape(a, (own.size,) + np.shape(a)[2:]) for a in parts)
            placed = _scatter(NormalEquations(None, None, None, meat, None, metric_sums, noise_grams), own,
                              answers.shape, None)
            state.sums = state.sums._replace(meat=placed.meat, metric_sums=placed.metric_sums,
                                             noise_grams=placed.noise_grams)
    finite = np.isfinite(state.sums.cost)
    exact = (answers | (not compact)) & moved_little
    out = []
    for m, material in enumerate(starts):
        row = []
        for s, start in enumerate(material):
            values = layout.unflatten(state.x[m, s], free, xp=np)
            params = dict(start, **{k: np.asarray(v) for k, v in values.items()})
            normal = state.sums.at_point(m, s)
            if metrics and not formed[m, s]:
                normal = normal._replace(meat=None, metric_sums=None, noise_grams=None)
            row.append(SolveOutcome(
                params, float(state.sums.cost[m, s]), steps=int(steps[m, s]),
                max_steps=bool(finite[m, s] and not converged[m, s] and steps[m, s] >= max_steps),
                nonfinite=not finite[m, s], normal=normal, exact=bool(exact[m, s]), answer=bool(answers[m, s])))
        out.append(row)
    return out
