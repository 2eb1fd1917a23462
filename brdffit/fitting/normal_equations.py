"""Normal matrices of a fit's residual Jacobian: JᵀJ, Jᵀr, rᵀr and Jᵀ diag(r²) J, for a batch of points.

J is taken with respect to the free physical parameters. One compiled *pass* evaluates, for every point of a
batch (materials × starts), the residuals and their tangents; the sums are formed on the host. The passes serve
the default solver (`brdffit.fitting.marquardt`, every step of the polish and of the full-data refinement) and
the covariance of a fit (`brdffit.fitting.uncertainty`): one compiled program per model structure and data
shape, whatever the stage or the solver's options.

Colour parameters hold one value per channel, and channel c of the residuals depends on channel c of a colour
parameter only (a model evaluates its channels independently; only shape parameters are shared). One
forward-mode tangent per parameter *name*, seeded with ones in every channel, therefore yields all of that
parameter's Jacobian columns at once: the tangent's channel c is ∂r[:, c]/∂p[c]. A fit with Q free names and
P free scalars needs Q Jacobian-vector products instead of P (Lambert + Cook-Torrance in RGB: 3 instead of 7).
`accumulate` forms the per-channel sums S[q, s, c] = Σ_n t_q[n, c] t_s[n, c] chunk by chunk and expands them
into the P × P matrices. `tests/test_normal_equations.py` checks the result against ``jax.jacfwd`` for every
lobe.
"""

from __future__ import annotations

import functools
import threading
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..arrays import on_device, on_host
from ..metrics import MODEL_FLOOR, NOISE_MIN_COS, metric_sums
from ..models.model import evaluate_pair
from .losses import get_loss
from .problem import BUCKET_CHUNK, PER_SAMPLE, FitData, Problem, physical_params, residuals_of, sample_pieces
from ..programs import Program
from .search import POLISH_STARTS

__all__ = ["NormalEquations", "pass_program", "chunks", "accumulate", "compile_seconds", "timed_first_calls",
           "shape_key", "metric_sums_of", "meat_of", "noise_grams_of", "NOISE_FORMS", "CHUNK_SAMPLES", "SLOTS",
           "SLOT_ROWS", "pass_pieces"]

CHUNK_SAMPLES = BUCKET_CHUNK  # padded data then splits into whole chunks
# A pass over one material's data of at most SLOTS × SLOT_ROWS samples runs on SLOTS slots of rows (`_slots`): the
# polish's SLOTS starts each on all the rows (at most SLOT_ROWS), or one point on SLOTS equal slices of its rows.
# Both are one compiled shape when the rows agree: a selection screens its candidates on SLOT_ROWS rows
# (`brdffit.select.SCREEN_SAMPLES`) and refits the one it chooses from one point on all of them, which for an
# RGL-EPFL file's 16,384 pairs is four slices of SLOT_ROWS: the refit runs the screen's program instead of compiling
# the largest program of the selection at its end (the chosen three Lafortune lobes: a second of CPU).
SLOTS = POLISH_STARTS
SLOT_ROWS = 4096
# The noise forms whose weighted Gram matrices an answer's pass forms (`noise_grams_of`): ``loss``, the residuals'
# own (JᵀJ per channel, the Laplace covariance's), then the candidates of `brdffit.fitting.noise`.
NOISE_FORMS = ("loss", "absolute", "relative", "signal", "cosine", "sigma")


class NormalEquations(NamedTuple):
    """The sums `accumulate` returns, as NumPy float64, in `Layout.flatten` order of the free parameters, with
    the batch's leading axes (materials, starts) on every field (none for `at_point`).

    Fields:
        jtj: JᵀJ ``(..., P, P)``.
        jtr: Jᵀr ``(..., P)``.
        cost: rᵀr ``(...)``.
        meat: Jᵀ diag(r²) J ``(..., P, P)`` (the sandwich covariance's middle), or None where the pass was not
            asked for it.
        channel_cost: rᵀr of each channel ``(..., C)``.
        metric_sums: the sums of `brdffit.metrics.metric_sums` ``(..., R, C)`` (its R rows: the metrics' and the
            noise models') at the evaluated point when `accumulate` was asked for them, else None
            (`brdffit.metrics.metrics_from_sums` turns them into the metrics).
        noise_grams: with the metric sums, the per-channel Gram matrices of the tangents weighted by each noise
            form's variance of the residuals, with the residuals scaled by the form in a last row
            (`noise_grams_of`) ``(..., F, Q + 1, Q + 1, C)``, F = `NOISE_FORMS`, Q the free names; else None.
    """

    jtj: np.ndarray
    jtr: np.ndarray
    cost: np.ndarray
    meat: np.ndarray
    channel_cost: np.ndarray
    metric_sums: np.ndarray
    noise_grams: np.ndarray = None

    def at_point(self, m: int, s: int) -> "NormalEquations":
        """The sums of point ``(m, s)`` of the batch."""
        return NormalEquations(self.jtj[m, s], self.jtr[m, s], float(self.cost[m, s]),
                               None if self.meat is None else self.meat[m, s], self.channel_cost[m, s],
                               None if self.metric_sums is None else self.metric_sums[m, s],
                               None if self.noise_grams is None else self.noise_grams[m, s])


def _tangent_groups(problem: Problem) -> list[tuple]:
    """The free names in groups, each group's tangents taken by one vmapped JVP (`_tangents`).

    The seeds of one JVP share its tangent axis, so every operation that any of them reaches carries all of them:
    an amplitude's seed, which reaches only the product with its lobe, then rides through the whole lobe with the
    shape parameters' seeds. When the amplitudes are at least as many as the other names, they get their own JVP,
    whose tangents reach only the products (the second JVP's primal is the same program, for XLA to share): a
    pass of Lambert + Cook-Torrance or Lambert + GGX then takes markedly less CPU time, while for 3 Lafortune lobes
    (4 amplitudes, 6 shape names) the split gained little and lengthened the compilation, so there all names stay
    in one."""
    amplitudes = tuple(n for n in problem.free if n in problem.linear)
    others = tuple(n for n in problem.free if n not in problem.linear)
    if amplitudes and others and len(amplitudes) >= len(others):
        return [amplitudes, others]
    return [problem.free]


def _tangents(problem: Problem, tree: dict, data: FitData):
    """For one point and one material: ``(C, Q + 1, N)``, row q the tangent of free name q (in ``problem.free``
    order) in each channel and row Q the residuals; and the model values ``(N, C)``.

    The seeds of a group (`_tangent_groups`) are stacked and the JVP is vmapped over them (what ``jax.jacfwd``
    does): the compiled program holds one copy of the model with a tangent axis and evaluates the primal once.
    One JVP per name, unrolled, held Q + 1 copies, which compiled and ran slower than the vmapped JVP."""
    def r(values):
        f = evaluate_pair(problem.model(physical_params(problem, {}, dict(data.fixed, **values))), data.pair)
        return residuals_of(problem, f, data), f

    rows = {}
    for names in _tangent_groups(problem):
        moving = {k: tree[k] for k in names}
        rest = {k: v for k, v in tree.items() if k not in names}
        seeds = {k: jnp.stack([(jnp.ones_like(v) if k == name else jnp.zeros_like(v)) for name in names])
                 for k, v in moving.items()}
        residuals, tangents, f = jax.vmap(
            lambda seed, rest=rest, moving=moving: jax.jvp(lambda m: r(dict(rest, **m)), (moving,), (seed,),
                                                           has_aux=True),
            out_axes=(None, 0, None))(seeds)
        rows.update(zip(names, tangents))
    tangents = jnp.stack([rows[name] for name in problem.free])
    return jnp.transpose(jnp.concatenate([tangents, residuals[None]]), (2, 0, 1)), f


_COMPILE_SECONDS = threading.local()  # per thread: `brdffit.select` fits candidates concurrently


@functools.lru_cache(maxsize=64)
def pass_program(structure: Problem):
    """The jitted pass of a problem structure (`Problem.structure`):
    ``fn(trees, data, materials=None, slotted=False) -> (A, f)`` with ``trees`` free name -> value ``(M, S) + shape``
    (materials, points of each), ``data`` a `FitData` with a leading material axis, ``A`` ``(M, S, C, Q + 1, N)``
    the tangents and residuals of `_tangents` and ``f`` ``(M, S, N, C)`` the model values. With ``materials``
    (integer indices ``(M,)``), row i of ``trees`` is evaluated on material ``materials[i]`` of ``data``, gathered
    inside the program: the data of a batch stay on the device, and a compact polish's passes move only the points
    and their indices (a host gather of the data at every step cost a sizeable share of a `fit_many`). With
    ``slotted``, every leaf of ``data`` has a slot axis after the material axis, of length S: point s is evaluated
    on slot s of the data (`_slots`). The first call of each shape compiles; the seconds are added to
    `compile_seconds`."""
    def point_tangents(tree, data):  # the programs' name in JAX's logs and profiles
        return _tangents(structure, tree, data)

    per_material = jax.vmap(jax.vmap(point_tangents, in_axes=(0, None)), in_axes=(0, 0))
    programs = (Program(per_material, f"pass {structure!r}"),
                Program(lambda trees, data, index: per_material(trees, jax.tree_util.tree_map(lambda a: a[index],
                                                                                              data)),
                        f"gathered pass {structure!r}"),
                Program(jax.vmap(jax.vmap(point_tangents, in_axes=(0, 0)), in_axes=(0, 0)),
                        f"slotted pass {structure!r}"))

    def fn(trees, data, materials=None, slotted=False):
        if slotted:
            return programs[2](trees, data)
        if materials is None:
            return programs[0](trees, data)
        return programs[1](trees, data, np.asarray(materials, dtype=np.int32))

    return timed_first_calls(fn, lambda trees, data, materials=None, slotted=False:
                             shape_key(trees, data) + (materials is None, slotted))


def shape_key(trees: dict, data: FitData) -> tuple:
    """The shapes that decide a pass's compilation: every other leaf's shape follows from the values' and the
    problem's (a cheap key: it is computed at every call)."""
    return (tuple(np.shape(v) for v in trees.values()), data.values.shape, str(data.values.dtype),
            tuple(sorted(data.fixed)))


def timed_first_calls(call, key):
    """``call`` with the seconds of its first call for each ``key(*args)`` (compilation, or loading it from JAX's
    persistent cache, and the call itself) added to `compile_seconds`."""
    seen = set()

    def fn(*args):
        signature = key(*args)
        if signature in seen:
            return call(*args)
        start = time.perf_counter()
        out = jax.block_until_ready(call(*args))
        seen.add(signature)
        _COMPILE_SECONDS.value = compile_seconds() + time.perf_counter() - start
        return out

    return fn


def compile_seconds() -> float:
    """Seconds this thread has spent in the first calls of passes (compilation, or loading it from JAX's
    persistent cache, and the call itself); the pipeline reports the difference over a fit."""
    return getattr(_COMPILE_SECONDS, "value", 0.0)


def timed(call):
    """``call()``, the seconds its passes spent compiling (`compile_seconds`) and the rest of its time."""
    start, compiled = time.perf_counter(), compile_seconds()
    out = call()
    compile_time = compile_seconds() - compiled
    return out, compile_time, time.perf_counter() - start - compile_time


def metric_sums_of(values: list, pieces: list[FitData], materials=None) -> np.ndarray:
    """The metric sums ``(M, S, R, C)`` of a pass's model values (`accumulate` with ``values=True``: one
    ``(M, S, N, C)`` array per piece) against the pieces' data (row i against material ``materials[i]``, when
    given), `brdffit.metrics.metric_sums` in NumPy on the host: they do not depend on the model, and a solver asks
    for them at its answers only (one point a material), so a compiled program only added its compilation to a
    first fit. The errors are ignored as XLA ignores them (a value below -1/cosθi has no
    log-loss term: NaN, as in the compiled sums)."""
    total = 0.0
    index = slice(None) if materials is None else np.asarray(materials)
    with np.errstate(all="ignore"):
        for f, piece in zip(values, pieces):
            f = np.asarray(f)
            data, mask, cos_i, sqrt_weight = (a[index][:, None] for a in on_host((piece.values, piece.mask,
                                                                                   piece.cos_i, piece.sqrt_weight)))
            per_sample, per_value = f.shape[:-1], f.shape  # every point of a material against its data
            total = total + metric_sums(f, np.broadcast_to(data, per_value), np.broadcast_to(mask, per_value),
                                        np.broadcast_to(cos_i, per_sample),
                                        np.broadcast_to(sqrt_weight ** 2, per_sample), xp=np)
    return total


def noise_grams_of(problem: Problem, tangents: list, values: list, pieces: list[FitData], materials=None,
                   laplace=None) -> np.ndarray:
    """Per channel, for each noise form of `NOISE_FORMS`, the Gram matrix of the tangents weighted by the form's
    variance of the residuals, with the data's residuals scaled by the form in a last row: rows
    t_n ρ_n √g_n (one per free name) and d_n / √g_n, where t_n are the tangents of the residual of sample n,
    d_n = f_n − y_n, ρ_n = |∂r/∂f| at the data (`brdffit.fitting.losses.residual_scale`: it carries a variance of
    the measured value, s² g_n, into the loss's units) and g_n the form's variance function (1 for ``absolute``,
    f̃² for ``relative``, f̃ for ``signal``, 1/(cos²θi w) for ``cosine``, σ² for ``sigma``, with f̃ and the
    cosine's floor as in `brdffit.metrics.metric_sums`). The block over the free names is Σ_n v_n t_n t_nᵀ with
    v_n = ρ_n² g_n, the middle of the noise-model covariance per unit scale (`brdffit.fitting.uncertainty`); the
    last diagonal entry Σ_n d_n²/g_n over every valid value gives the form's maximum-likelihood scale. The ``loss``
    form's rows are the pass's own tangents and residuals (v = 1): the Laplace covariance's JᵀJ and rᵀr.

    Arguments:
        problem: the `Problem`.
        tangents: a pass's tangents and residuals of each piece ``(M, S, C, Q + 1, N)`` (`accumulate` with
            ``values=True``); values: its model values ``(M, S, N, C)``.
        pieces: the data (leading material axis), as passed to the pass.
        materials: integer indices ``(M,)`` of the pieces' materials (None: the pieces' own M).
        laplace: the ``loss`` form's sums ``(M, S, C, Q + 1, Q + 1)`` where the caller has them (the pass's own
            Gram matrices, so that the Laplace covariance is the same to the last bit), else formed here.

    Returns:
        ``(M, S, F, Q + 1, Q + 1, C)``.
    """
    q = len(problem.free)
    weight = get_loss(problem.loss).weight
    index = None if materials is None else np.asarray(materials)
    total = 0.0
    with np.errstate(all="ignore"):
        for a, f, piece in zip(tangents, values, pieces):
            a = np.asarray(a)
            t = a[..., :q, :]  # (M, S, C, Q, N)
            f = np.asarray(f)  # (M, S, N, C)
            data, mask, cos_i, sqrt_weight, sigma, eps = (np.asarray(x) if index is None else np.asarray(x)[index]
                                                          for x in on_host((piece.values, piece.mask, piece.cos_i,
                                                                            piece.sqrt_weight, piece.sigma,
                                                                            piece.eps)))
            rho = np.stack([np.where(mask[m], np.abs(np.asarray(weight(data[m], cos_i[m], sqrt_weight[m], sigma[m],
                                                                         eps[m]))), 0.0)
                            for m in range(data.shape[0])])[:, None]  # (M, 1, N, C)
            d = np.where(mask[:, None], f - data[:, None], 0.0)  # (M, S, N, C)
            floored = np.maximum(f, MODEL_FLOOR)
            omega2 = (np.maximum(cos_i, NOISE_MIN_COS) ** 2 * sqrt_weight ** 2)[:, None, :, None]
            variance = {"absolute": np.ones_like(f), "relative": floored * floored, "signal": floored,
                        "cosine": np.where(omega2 > 0, 1.0 / np.where(omega2 > 0, omega2, 1.0), 0.0) + 0 * f,
                        "sigma": sigma[:, None] ** 2 + 0 * f}
            grams = []
            for form in NOISE_FORMS:
                if form == "loss":
                    grams.append(_grams(a) if laplace is None else np.zeros(a.shape[:3] + (q + 1, q + 1)))
                    continue
                root = np.sqrt(variance[form])
                rows = np.concatenate([t * np.moveaxis(rho * root, -1, -2)[..., :, None, :],
                                       np.moveaxis(np.where(root > 0, d / np.where(root > 0, root, 1.0), 0.0),
                                                   -1, -2)[..., :, None, :]], axis=-2)
                grams.append(_grams(rows))
            total = total + np.stack(grams, axis=2)  # (M, S, F, C, Q + 1, Q + 1)
        if laplace is not None:
            total[:, :, 0] = laplace
        return np.moveaxis(total, 3, -1)


def chunks(data: FitData, size: int = CHUNK_SAMPLES) -> list[FitData]:
    """`sample_pieces` of one material's ``data`` (no material axis): equally shaped chunks of ``size`` samples,
    each with a leading material axis of 1 (bounds the memory of the tangents; split once and reuse the list when
    accumulating repeatedly)."""
    return sample_pieces(jax.tree_util.tree_map(lambda a: a[None], on_host(data)), size)


def accumulate(problem: Problem, trees: dict, pieces: list[FitData], metrics: bool = False,
               values: bool = False, meat: bool = True, materials=None, first: int | None = None):
    """JᵀJ, Jᵀr, rᵀr, Jᵀ diag(r²) J and the per-channel rᵀr over all of the data, for every point of a batch.

    Arguments:
        problem: the `Problem`.
        trees: free name -> physical values ``(M, S) + shape``: S points for each of M materials.
        pieces: the data of the M materials (leading material axis), whole or in chunks (`chunks`).
        metrics: also sum the goodness-of-fit terms of the model values (`metric_sums_of`).
        values: also return the pass's arrays of each piece: the tangents and residuals ``(M, S, C, Q + 1, N)``
            (host) and the model values ``(M, S, N, C)`` (device). A solver keeps them for its current points and
            forms the meat (`meat_of`) and the metric sums (`metric_sums_of`) of its answer only.
        meat: form Jᵀ diag(r²) J (else the field is None): a sizeable share of the host's work in a pass.
        materials: integer indices ``(M,)``: point row i is evaluated on material ``materials[i]`` of the pieces
            (gathered on the device, `pass_program`); None: the pieces have the M materials of ``trees``.
        first: form the sums of the first ``first`` points of each material only (S = ``first`` in what is
            returned): the others are copies evaluated so that the pass has a shape another solve compiled.

    Returns:
        The `NormalEquations`, each field with leading axes ``(M, S)``; with ``values``, the pair
        ``(sums, [(tangents, model values) per piece])``.

    Raises:
        ValueError: a value of the wrong shape.
    """
    batch = None
    for name in problem.free:
        want = problem.layout[name].shape
        got = np.shape(trees[name])
        if len(got) < 2 or got[2:] != want or (batch is not None and got[:2] != batch):
            raise ValueError(f"parameter {name!r} has shape {got}; expected (materials, points) + {want}")
        batch = got[:2]
    index, incidence = problem.layout.channel_incidence(problem.free)
    fn = pass_program(problem.structure)
    q = len(problem.free)
    gram, kept = 0.0, []
    slots = _slots(batch, pieces, materials)
    # A diverged solver (undamped Gauss-Newton far away) can overflow the products: inf/NaN then reach the
    # covariance as infinite standard errors, which is what they mean, without a warning per chunk.
    with np.errstate(over="ignore", invalid="ignore"):
        for piece in pieces:
            # The per-channel Gram matrices on the host: faster on the CPU than the same reductions in XLA (see
            # `_grams`), and a (M, S, C, Q + 1, N) transfer per chunk on a GPU.
            if slots is None:
                a, f = fn(trees, piece, materials)
            else:
                a, f = fn({k: np.broadcast_to(v, (1, SLOTS) + np.shape(v)[2:]) for k, v in trees.items()},
                          _slotted(piece, slots), None, True)
            a = np.asarray(a)
            if slots == "rows":  # the slices joined again in the samples' order: (1, 1, C, Q + 1, N), (1, 1, N, C)
                joined = np.ascontiguousarray(np.moveaxis(a, 1, -2))
                a = joined.reshape(a.shape[:1] + (1,) + a.shape[2:-1] + (-1,))
                f = jnp.reshape(f, (1, 1, -1, f.shape[-1]))
            if first is not None:
                a, f = a[:, :first], f[:, :first]
            kept.append((a, f))
            gram = gram + _grams(a)  # (M, S, C, Q+1, Q+1): tangents and residuals
        grams = noise_grams_of(problem, [a for a, _ in kept], [f for _, f in kept], pieces, materials,
                               laplace=gram) if metrics else None
        gram = np.moveaxis(np.asarray(gram), 2, -1)  # (M, S, Q+1, Q+1, C)
        jtr = np.sum(incidence * gram[..., index, q, :], axis=-1)
        channel_cost = np.array(gram[..., q, q, :], dtype=float)
        sums = NormalEquations(jtj=_expand(problem, gram[..., :q, :q, :]), jtr=jtr,
                               cost=np.sum(channel_cost, axis=-1),
                               meat=meat_of(problem, [a for a, _ in kept]) if meat else None,
                               channel_cost=channel_cost,
                               metric_sums=(metric_sums_of([f for _, f in kept], pieces, materials) if metrics
                                            else None),
                               noise_grams=grams)
    return (sums, kept) if values else sums


def _slots(batch: tuple, pieces: list[FitData], materials) -> str | None:
    """How a pass lays out a batch of one material on `SLOTS` slots (`SLOT_ROWS`), or None for the plain pass:
    ``"points"`` for SLOTS points on one piece of at most SLOT_ROWS samples (each slot a point, on all the rows),
    ``"rows"`` for one point on one piece of at most SLOTS × SLOT_ROWS samples (each slot a slice of the rows)."""
    if materials is not None or len(pieces) != 1 or batch[0] != 1:
        return None
    rows = pieces[0].values.shape[1]
    if batch[1] == SLOTS and rows <= SLOT_ROWS:
        return "points"
    if batch[1] == 1 and rows % SLOTS == 0 and rows <= SLOTS * SLOT_ROWS:
        return "rows"
    return None


def pass_pieces(pieces: list[FitData], batch: tuple) -> list[FitData]:
    """The pieces as the passes over a batch of shape ``batch`` ``(M, S)`` read them at every step of a solve: as they
    are where the passes lay them out on slots (`_slotted` moves that layout to the device once), else on the device
    (the pipeline keeps its data on the host, docs/fitting.md)."""
    if _slots(batch, pieces, None) is not None:
        return pieces
    return [on_device(piece) for piece in pieces]


_SLOTTED = threading.local()  # per thread: the last pieces laid out on slots, with the pieces themselves


def _slotted(piece: FitData, slots: str) -> FitData:
    """``piece`` (one material) with a slot axis of `SLOTS` after its material axis, on the device: every slot the
    same rows (``"points"``) or consecutive slices of them (``"rows"``); the per-material fields repeated. The
    last few are kept per thread (a solver passes over the same pieces at every step)."""
    cache = getattr(_SLOTTED, "pieces", None)
    if cache is None:
        cache = _SLOTTED.pieces = {}
    held, out = cache.get((id(piece), slots), (None, None))
    if held is piece:
        return out
    fields = on_host(piece._asdict())

    def laid(name, a):
        if name in PER_SAMPLE and slots == "rows":
            return a.reshape((1, SLOTS, a.shape[1] // SLOTS) + a.shape[2:])
        return np.broadcast_to(a[:, None], (1, SLOTS) + a.shape[1:])

    out = FitData(**on_device({name: jax.tree_util.tree_map(lambda a, name=name: laid(name, a), value)
                               for name, value in fields.items()}))
    if len(cache) >= 4:
        cache.pop(next(iter(cache)))
    cache[(id(piece), slots)] = (piece, out)
    return out


def _grams(a: np.ndarray) -> np.ndarray:
    """``a aᵀ`` of each of a batch of short, wide matrices ``(..., R, N)``. ``matmul`` calls BLAS once per product,
    which costs more than ``einsum``'s plain loop for R ≤ 3 (a `fit_many` pass of Lambert + GGX: thousands of
    (3, N) products) and less from R = 4 on, where the gap grows with R (a three-lobe Lafortune pass: R = 14)."""
    if a.shape[-2] <= 3:
        return np.einsum("...in,...jn->...ij", a, a)
    return a @ np.swapaxes(a, -1, -2)


@functools.lru_cache(maxsize=256)
def _expansion(problem: Problem) -> tuple:
    """Where each scalar pair's entry of `_expand` comes from: ``(single, shared, names)`` with ``single`` ``(P, P)``
    the flat index into a ``(Q, Q, C)`` array of the one channel the pair shares (a colour scalar's own, with a
    shape scalar or the same channel's colour scalar), -1 where the pair shares no channel or is two shape scalars
    (every channel); ``shared`` the shape scalars' positions and ``names`` their names' indices."""
    index, incidence = problem.layout.channel_incidence(problem.free)
    q, channels = len(problem.free), incidence.shape[1]
    own = incidence.sum(axis=1) == 1  # one channel: a colour scalar (or any scalar of one-channel data)
    channel = np.argmax(incidence, axis=1)
    a, b = np.meshgrid(np.arange(index.size), np.arange(index.size), indexing="ij")
    pair_channel = np.where(own[a], channel[a], channel[b])
    meets = (own[a] & own[b] & (channel[a] == channel[b])) | (own[a] != own[b])
    single = np.where(meets, (index[a] * q + index[b]) * channels + pair_channel, -1)
    shared = np.flatnonzero(~own)
    return single, shared, index[shared]


def _expand(problem: Problem, sums):
    """Per-channel sums over the free names ``(M, S, Q, Q, C)`` expanded to the scalars' ``(M, S, P, P)``: entry
    (i, j) sums the channels that scalars i and j both act on (a gather, not a (P, P, C) product: a 31-band
    spectrum has P = 63 scalars for Lambert + GGX)."""
    single, shared, names = _expansion(problem)
    sums = np.asarray(sums)
    flat = sums.reshape(sums.shape[:-3] + (-1,))
    out = np.where(single >= 0, np.take(flat, np.maximum(single, 0), axis=-1), 0.0)
    if shared.size:
        total = sums.sum(axis=-1)
        out[..., shared[:, None], shared[None, :]] = total[..., names[:, None], names[None, :]]
    return out


def meat_of(problem: Problem, tangents: list) -> np.ndarray:
    """Jᵀ diag(r²) J ``(M, S, P, P)`` from a pass's tangents and residuals (`accumulate` with ``values=True``)."""
    q = len(problem.free)
    total = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for a in tangents:
            weighted = a[..., :q, :] * a[..., q:, :]
            total = total + _grams(weighted)
        return _expand(problem, np.moveaxis(np.asarray(total), 2, -1))
