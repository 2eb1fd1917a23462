r"""Separable least squares: the linear amplitudes solved exactly for each value of the other parameters.

Most colour parameters (diffuse albedo ρd, specular amplitudes ks, Ashikhmin-Shirley's rs, the toon tones) enter
the BRDF affinely, channel by channel: with the other parameters θ held, f_c = f₀,c(θ) + Σ_k a_k,c B_k,c(θ). For a
linear loss r = w (f − f_d) the best amplitudes for given θ solve a small bounded linear least-squares problem
per channel,

    a*_c(θ) = argmin_{lo <= a <= hi} ‖w_c (f₀,c + B_c a − f_d,c)‖²,

and the solver minimises the *projected* residual r(θ, a*(θ)) over θ alone: variable projection (Golub & Pereyra,
SIAM J. Numer. Anal. 10, 1973; Kaufman, BIT 15, 1975). The nonlinear solver then sees only roughness, exponents,
σ, f₀/η and lobe directions (one to a few unknowns instead of 3 per amplitude), an amplitude that the data do not
want sits exactly on its bound instead of saturating a transform, and `lambert` is a single linear solve.

The bounded problem is solved exactly by enumerating its active sets: each amplitude is free, at its lower or at
its upper bound (2 or 3 states; K amplitudes give at most 3^K systems of size K, e.g. 24 for ρd and three
Lafortune lobes). The optimum is the feasible candidate of lowest objective, since the optimum's own active set
reproduces it and every feasible candidate is a point of the box. Everything is plain JAX, so the projected
residual is jitted, vmapped over starts and materials and differentiated by the solver like any residual
(forward-mode through the chosen system: the exact derivative of the projected residual on its active set).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..models.model import evaluate_pair
from .losses import get_loss
from .problem import FitData, Problem

__all__ = ["amplitude_basis", "adds_to_offset", "amplitude_sums", "same_in_every_channel", "one_channel_basis",
           "channel_grams", "weights", "solve_box", "box_patterns", "project"]

# Relative ridge added to the amplitude normal matrix: keeps the candidate systems solvable when a basis
# function vanishes on the data (a lobe that no sample sees) or two coincide (lambert+lambert); far below any
# conditioning the data can support.
_RIDGE = 1e-13
# A basis column whose weighted squared norm on the data is below this is no column: its amplitude stays on its
# lower bound. Such a lobe (a spike between the samples: Ward with α = 0.002 on 300 uniform samples) contributes
# < 1e-100 of a unit amplitude at every sample; it could matter only with an amplitude beyond 1e97, where its
# Gram entries are float64 denormals and the solve returned ks = 4e158 at a cost that rounding made 0, which then
# won the search.
_NEGLIGIBLE_COLUMN = 1e-200


def amplitude_basis(problem: Problem, params: dict, names: tuple, data: FitData):
    """The affine decomposition f = f₀ + Σ_k B_k a_k of the model in the amplitudes ``names``.

    Each lobe is evaluated on its own: once with its amplitudes at 0 (its part of f₀) and once per amplitude at 1
    (the others at 0) for that amplitude's B. A channel's value depends only on that channel's amplitude, so
    ones in every channel give every channel's column at once. Lobes without such amplitudes go into f₀. A lobe
    that is zero with those amplitudes at 0 (`adds_to_offset`) is not evaluated there: in a search or a pass of
    Lambert + GGX that evaluation would be a sizeable share of the GGX lobe's.

    Arguments:
        problem: the `Problem`.
        params: physical values of every parameter (the values of ``names`` are ignored).
        names: the linear amplitudes (colour parameters declared ``linear``).
        data: the `FitData`.

    Returns:
        ``(f0, basis)``: f₀ ``(N, C)`` and B ``(N, C, K)``, ``basis[n, c, k]`` = ∂f[n, c]/∂a_k[c]; both zero
        unless the sample lies above the horizon.
    """
    layout = problem.layout
    pair = data.pair
    shape = pair.above.shape + (problem.channels,)
    f0 = jnp.zeros(shape, dtype=pair.wi.dtype)
    columns = {}
    for j, lobe in enumerate(problem.lobes):
        local = layout.local_params(params, j)
        mine = [slot for slot in layout.lobe_slots(j) if slot.name in names]
        zero = dict(local, **{slot.local: jnp.zeros(problem.channels) for slot in mine})
        base = jnp.broadcast_to(lobe(zero, pair), shape) if adds_to_offset(problem, j, names) else 0.0
        f0 = f0 + base
        for slot in mine:
            unit = dict(zero, **{slot.local: jnp.ones(problem.channels)})
            columns[slot.name] = jnp.broadcast_to(lobe(unit, pair), shape) - base
    above = pair.above[..., None]
    basis = jnp.stack([columns[a] for a in names], axis=-1)
    return jnp.where(above, f0, 0.0), jnp.where(above[..., None], basis, 0.0)


def adds_to_offset(problem: Problem, j: int, names: tuple) -> bool:
    """Whether lobe ``j`` is not zero with the amplitudes ``names`` at 0, and so adds to f₀ (`amplitude_basis`):
    it declares an offset (`Lobe.offset`, Ashikhmin-Shirley's), has none of those amplitudes, or has another
    amplitude that keeps its value (a fixed one: a toon lobe's ``rho_shade`` or a second Lafortune lobe's ``ks``
    fixed beside a free one, whose part the free amplitude's column held before, 2026-12-04).

    Arguments:
        problem: the `Problem`.
        j: the lobe's index.
        names: the projected amplitudes.
    """
    slots = problem.layout.lobe_slots(j)
    return (problem.lobes[j].offset or not any(slot.name in names for slot in slots)
            or any(slot.spec.linear and slot.name not in names for slot in slots))


@functools.lru_cache(maxsize=64)
def box_patterns(lower: tuple, upper: tuple) -> np.ndarray:
    """Every active-set pattern of a box: code 0 free, 1 at the lower bound, 2 at the upper bound.

    Arguments:
        lower, upper: the bounds of each amplitude (infinite for none).

    Returns:
        ``(P, K)`` integer codes.
    """
    states = [[0] + ([1] if math.isfinite(lo) else []) + ([2] if math.isfinite(hi) else [])
              for lo, hi in zip(lower, upper)]
    return np.array(list(itertools.product(*states)), dtype=int).reshape(-1, len(states))


def _spd_solve(a, b, xp=jnp):
    """Solve a x = b for small symmetric positive definite ``a`` ``(..., K, K)`` by a Cholesky factorisation
    unrolled over K (batched over the leading axes; ``xp`` is `jax.numpy` or ``numpy``). For the few amplitudes
    of a model this compiles in a fraction of the time of `jnp.linalg.solve`'s pivoted LU, which dominated a
    fit's compilation."""
    k = a.shape[-1]
    low = [[None] * k for _ in range(k)]
    for j in range(k):
        diag = a[..., j, j] - sum(low[j][m] ** 2 for m in range(j))
        low[j][j] = xp.sqrt(xp.maximum(diag, 1e-300))
        for i in range(j + 1, k):
            low[i][j] = (a[..., i, j] - sum(low[i][m] * low[j][m] for m in range(j))) / low[j][j]
    z = []
    for i in range(k):
        z.append((b[..., i] - sum(low[i][m] * z[m] for m in range(i))) / low[i][i])
    x = [None] * k
    for i in reversed(range(k)):
        x[i] = (z[i] - sum(low[m][i] * x[m] for m in range(i + 1, k))) / low[i][i]
    return xp.stack(x, axis=-1)


def _scaled_system(gram, rhs, xp):
    """``(diagonal, scale, g, b)``: the Jacobi-scaled system of the bounded solves (the basis functions of a diffuse
    and a sharp lobe differ by decades in magnitude), with the relative ridge `_RIDGE`."""
    k = gram.shape[-1]
    diagonal = xp.diagonal(gram, axis1=-2, axis2=-1)
    scale = xp.sqrt(xp.maximum(diagonal, _NEGLIGIBLE_COLUMN))  # (..., K)
    return diagonal, scale, gram / (scale[..., :, None] * scale[..., None, :]) + _RIDGE * np.eye(k), rhs / scale


def _negligible(diagonal, lower):
    """``(..., K)``: the amplitudes whose basis column is negligible (`_NEGLIGIBLE_COLUMN`) and which have a lower
    bound to stay on."""
    return (diagonal < _NEGLIGIBLE_COLUMN) & np.isfinite(lower)


def _inside(a, lower, upper, xp, slack: float = 1e-10):
    """Whether each solution ``(..., K)`` lies in the box, to a relative ``slack`` (negative: that far inside)."""
    slack = slack * (1.0 + xp.abs(a))
    return xp.all((a >= lower - slack) & (a <= upper + slack), axis=-1)


def _enumerate_box_qp(gram, rhs, lower, upper, patterns, xp=jnp):
    """argmin ½ aᵀ G a − bᵀ a over lower <= a <= upper, by enumerating the active sets (see the module doc).

    Arguments:
        gram: G ``(..., K, K)``, symmetric positive semi-definite (leading axes batch independent problems).
        rhs: b ``(..., K)``.
        lower, upper: ``(K,)`` NumPy bounds (±inf for none).
        patterns: `box_patterns` of the bounds.
        xp: `jax.numpy` (traced, differentiated through `_box_qp`) or ``numpy`` (host solves, `solve_box`).

    Returns:
        ``(a, free)``: the optima ``(..., K)`` and the masks of their amplitudes off their bounds.
    """
    k = gram.shape[-1]
    diagonal, scale, g, b = _scaled_system(gram, rhs, xp)
    lo = np.where(np.isfinite(lower), lower, 0.0)
    hi = np.where(np.isfinite(upper), upper, 0.0)
    codes = np.asarray(patterns)
    free = (codes == 0).astype(float)  # (P, K)
    held = np.where(codes == 1, lo, np.where(codes == 2, hi, 0.0)) * scale[..., None, :]  # (..., P, K) scaled
    # Each pattern's system: the free rows of G (its free block plus the ridge, positive definite) and identity
    # rows that hold the others; all P systems solved at once.
    lhs = free[:, :, None] * g[..., None, :, :] * free[:, None, :] + np.eye(k) * (1.0 - free)[:, :, None]
    cand = _spd_solve(lhs, free * (b[..., None, :] - held @ g) + held, xp)  # (..., P, K) scaled
    a = cand / scale[..., None, :]
    feasible = _inside(a, lower, upper, xp)
    # A negligible column's amplitude is never free (`_NEGLIGIBLE_COLUMN`; an amplitude without a lower bound
    # has no other pattern, and keeps its solve).
    feasible = feasible & ~xp.any(_negligible(diagonal, lower)[..., None, :] & (free > 0), axis=-1)
    objective = 0.5 * xp.sum(cand * (cand @ g), axis=-1) - xp.sum(cand * b[..., None, :], axis=-1)
    best = xp.argmin(xp.where(feasible, objective, np.inf), axis=-1)
    chosen = xp.take_along_axis(a, best[..., None, None], axis=-2)[..., 0, :]
    return xp.clip(chosen, lower, upper), xp.asarray(free)[best]


def _box_qp(lower: tuple, upper: tuple):
    """The bounded solve for these bounds as a function of (G, b), with its derivative on the optimum's active
    set: da = G_FF⁻¹ (db − dG a) on the free amplitudes F, 0 on those held by a bound. Differentiating the
    enumeration itself would carry every candidate system through every tangent (it doubled a fit's
    compilation time). Made anew for each trace: a cached custom_jvp kept the float64 trace of its rule for a
    later float32 fit (`jax.enable_x64(False)`)."""
    lo, hi = np.asarray(lower), np.asarray(upper)
    patterns = box_patterns(lower, upper)

    @jax.custom_jvp
    def solve(gram, rhs):
        return _enumerate_box_qp(gram, rhs, lo, hi, patterns)[0]

    @solve.defjvp
    def solve_jvp(primals, tangents):
        gram, rhs = primals
        d_gram, d_rhs = tangents
        a, free = _enumerate_box_qp(gram, rhs, lo, hi, patterns)
        k = gram.shape[0]
        scale = jnp.sqrt(jnp.maximum(jnp.diag(gram), _NEGLIGIBLE_COLUMN))
        g = gram / jnp.outer(scale, scale) + _RIDGE * jnp.eye(k)
        lhs = free[:, None] * g * free[None, :] + jnp.diag(1.0 - free)
        right = free * (d_rhs - d_gram @ a) / scale
        return a, _spd_solve(lhs, right) / scale

    return solve


def amplitude_sums(problem: Problem, params: dict, names: tuple, data: FitData, shared: bool = False):
    """The normal equations of the amplitudes ``names`` for residuals ``w · (f₀ + B a − f_d)``, w the loss's
    weights (`Loss.weight`, linearised at the data for a nonlinear loss).

    With ``shared``, every colour parameter other than ``names`` has the same value in every channel (as in the
    search's candidates, `brdffit.fitting.search`), so that f₀ and B, which evaluate each channel from that
    channel's values alone, are the same in every channel: they are evaluated for one channel, and the weights,
    which differ between channels (the mask; a nonlinear loss's linearisation), enter the sums as matrix products
    over the samples: G_c = Σ_n w²_nc B_n B_nᵀ, b_c = Σ_n B_n w²_nc (f_d − f₀)_nc. On a CPU that scores a
    Lambert + GGX candidate faster than the per-channel products of the weighted basis.

    Arguments:
        problem: the `Problem`.
        params: physical values of every parameter (the values of ``names`` are ignored).
        names: the linear amplitudes (K names).
        data: the `FitData`.
        shared: the other colour parameters are the same in every channel (see above; else the result is wrong).

    Returns:
        ``(c0, gram, rhs)``: ‖w (f_d − f₀)‖² per channel ``(C,)``, G = (wB)ᵀ(wB) ``(C, K, K)`` and
        b = (wB)ᵀ w (f_d − f₀) ``(C, K)``, so that the squared residual norm is c₀ − 2aᵀb + aᵀGa.
    """
    if not shared:
        _, _, weighted, target = _amplitude_system(problem, params, names, data)
        return (jnp.sum(target * target, axis=0),) + _normal_sums(weighted, target)
    f0, basis = one_channel_basis(problem, params, names, data)
    squared = jnp.square(weights(problem, data))  # (N, C)
    residual = data.values - f0[:, None]
    gram = jnp.transpose(channel_grams(basis, squared), (2, 0, 1))
    return jnp.sum(squared * residual * residual, axis=0), gram, (basis.T @ (squared * residual)).T


def same_in_every_channel(problem: Problem, values: dict) -> bool:
    """Whether every colour value in ``values`` (name -> host array, leading axes allowed) but the projected
    amplitudes' is the same in all channels: then f₀ and the amplitudes' basis are too, since a lobe evaluates a
    channel from that channel's values alone (`one_channel_basis`)."""
    specs, linear = problem.specs, set(problem.linear)
    return all(np.all(np.asarray(value) == np.asarray(value)[..., :1]) for name, value in values.items()
               if specs[name].colour and name not in linear)


def one_channel_basis(problem: Problem, params: dict, names: tuple, data: FitData):
    """`amplitude_basis` of channel 0 alone, evaluated for one channel: ``(f0 (N,), basis (N, K))``, every
    channel's where `same_in_every_channel` holds of ``params``."""
    colour = {spec.name for spec in problem.specs if spec.colour}
    first = {name: (value[..., :1] if name in colour else value) for name, value in params.items()}
    f0, basis = amplitude_basis(dataclasses.replace(problem, channels=1), first, names, data)
    return f0[:, 0], basis[:, 0, :]


def channel_grams(functions, squared):
    """Σ_n squared[n, c] e_n e_nᵀ of functions ``(N, L)`` that every channel shares, for each channel's squared
    weights ``(N, C)``: ``(L, L, C)``, one matrix product."""
    n, count = functions.shape
    return (functions.T @ (functions[:, :, None] * squared[:, None, :]).reshape(n, -1)).reshape(count, count, -1)


def _amplitude_system(problem: Problem, params: dict, names: tuple, data: FitData):
    """``(f0, basis, weighted basis w·B, target w·(f_d − f₀))`` of the amplitudes ``names``."""
    weight = weights(problem, data)
    f0, basis = amplitude_basis(problem, params, names, data)
    return f0, basis, basis * weight[..., None], (data.values - f0) * weight


def _normal_sums(weighted, target):
    return jnp.einsum("nck,ncl->ckl", weighted, weighted), jnp.einsum("nck,nc->ck", weighted, target)


def _projection(problem: Problem, params: dict, data: FitData):
    """The parameters with `Problem.linear` solved within their bounds (traced: the enumerated active-set solve
    with its derivative, `_box_qp`), the model values there, the weighted basis and the weights."""
    names = problem.linear
    specs = problem.specs
    f0, basis, weighted, target = _amplitude_system(problem, params, names, data)
    gram, rhs = _normal_sums(weighted, target)
    solve = _box_qp(tuple(float(specs[a].lower) for a in names), tuple(float(specs[a].upper) for a in names))
    stacked = jax.vmap(solve)(gram, rhs)  # (C, K)
    amplitudes = {a: stacked[:, k] for k, a in enumerate(names)}
    f = f0 + jnp.einsum("nck,ck->nc", basis, stacked)
    return dict(params, **amplitudes), f, weighted, weights(problem, data)


def project(problem: Problem, params: dict, data: FitData):
    """The parameters with the amplitudes `Problem.linear` solved exactly, and the model values there.

    The weights are the loss's own (`Loss.weight`): exact for a linear loss, the linearisation at the data for a
    nonlinear one.

    Arguments:
        problem: the `Problem`.
        params: physical values of every parameter (those of the amplitudes are replaced).
        data: the `FitData`.

    Returns:
        ``(params, f_model)``: the completed parameters and the model values ``(N, C)`` at them.
    """
    if not problem.linear:
        return params, evaluate_pair(problem.model(params), data.pair)
    params, f, _, _ = _projection(problem, params, data)
    return params, f


def solve_box(gram, rhs, lower, upper) -> np.ndarray:
    """argmin ½ aᵀ G a − bᵀ a over the box [lower, upper]: the same exact active-set solve as the fits use, in
    NumPy on the host (the full-data passes of `brdffit.fitting.marquardt` re-solve the amplitudes from their
    sums this way, batched over points and channels).

    The problem is convex, so where its unconstrained optimum (the all-free pattern, the enumeration's first)
    lies in the box and no column is negligible, it is the optimum: only the other systems enumerate their active
    sets. An optimum within 1e-8 (relative) of a bound is enumerated too, so that an amplitude that the data do
    not want lands exactly on its bound, as the enumeration puts it (a free solve left ks = 2e-15). Nearly all of
    a search's or a polish's systems are inside, and enumerating all their patterns cost a noticeable share of a
    `fit_many`.

    Arguments:
        gram: G ``(..., K, K)``; rhs: b ``(..., K)``; lower, upper: sequences of K bounds (±inf for none).

    Returns:
        The optima as a NumPy array ``(..., K)``.
    """
    lower = np.array([float(v) for v in lower])
    upper = np.array([float(v) for v in upper])
    gram, rhs = np.asarray(gram, dtype=float), np.asarray(rhs, dtype=float)
    diagonal, scale, g, b = _scaled_system(gram, rhs, np)
    a = _spd_solve(g, b, np) / scale
    done = _inside(a, lower, upper, np, slack=-1e-8) & ~np.any(_negligible(diagonal, lower), axis=-1)
    if not np.all(done):
        rest = ~done
        a[rest] = _enumerate_box_qp(gram[rest], rhs[rest], lower, upper, box_patterns(tuple(lower), tuple(upper)),
                                    xp=np)[0]
    return np.clip(a, lower, upper)


def weights(problem: Problem, data: FitData):
    """The loss's weights ``(N, C)`` (`Loss.weight`: for a nonlinear loss, linearised at the data), 0 where a value
    is missing."""
    w = get_loss(problem.loss).weight(data.values, data.cos_i, data.sqrt_weight, data.sigma, data.eps)
    return jnp.where(data.mask, w, 0.0)


def projected_residuals(problem: Problem, to_params, y, data: FitData):
    """The residuals of the projected problem, r(θ) = w (f₀(θ) + B(θ) a*(θ) − f_d), with Kaufman's derivative.

    The derivative is Kaufman's (BIT 15, 1975, Eq. 8): dr = P⊥ ∂r/∂θ|_a dθ, with P⊥ the projection off the span
    of the weighted basis columns of the free amplitudes, channel by channel. It drops the term of the exact
    Golub-Pereyra derivative that vanishes with the residual, and keeps a Gauss-Newton solver converging as
    fast in practice while the basis evaluation and the bounded solve stay out of every tangent.

    Arguments:
        problem: the `Problem` (its `linear` names are projected; it needs a linear loss).
        to_params: ``(y, data) -> params``, the physical values of every parameter from the solver's variables.
        y: the solver's variables.
        data: the `FitData`.

    Returns:
        ``(N, C)`` residuals.
    """

    def primal(y, data):
        params, f, weighted, weight = _projection(problem, to_params(y, data), data)
        return params, weighted, weight * (f - data.values)

    @jax.custom_jvp
    def residuals(y, data):
        return jnp.where(data.mask, primal(y, data)[2], 0.0).astype(data.values.dtype)

    @residuals.defjvp
    def residuals_jvp(primals, tangents):
        y, data = primals
        dy = tangents[0]
        params, weighted, r = primal(y, data)
        names = problem.linear
        held = {a: params[a] for a in names}

        def plain(y):  # the residuals with the amplitudes held at their optimum
            p = dict(to_params(y, data), **held)
            return jnp.where(data.mask, weights(problem, data) * (evaluate_pair(problem.model(p), data.pair)
                                                                   - data.values), 0.0)

        t = jax.jvp(plain, (y,), (dy,))[1]  # (N, C)
        specs = problem.specs
        lower = jnp.asarray([specs[a].lower for a in names])
        upper = jnp.asarray([specs[a].upper for a in names])
        values = jnp.stack([params[a] for a in names], axis=-1)  # (C, K)
        free = ((values > lower + 1e-12) & (values < upper - 1e-12)).astype(r.dtype)
        gram = jnp.einsum("nck,ncl->ckl", weighted, weighted)
        scale = jnp.sqrt(jnp.maximum(jnp.einsum("ckk->ck", gram), _NEGLIGIBLE_COLUMN))
        g = gram / (scale[:, :, None] * scale[:, None, :]) + _RIDGE * jnp.eye(len(names))
        lhs = free[:, :, None] * g * free[:, None, :] + jnp.eye(len(names)) * (1.0 - free)[:, :, None]
        coefficient = _spd_solve(lhs, free * jnp.einsum("nck,nc->ck", weighted, t) / scale) / scale
        dr = t - jnp.einsum("nck,ck->nc", weighted, free * coefficient)
        dtype = data.values.dtype  # the working precision (float32 inside jax.enable_x64(False))
        return jnp.where(data.mask, r, 0.0).astype(dtype), jnp.where(data.mask, dr, 0.0).astype(dtype)

    return residuals(y, data)
