"""The normal equations of a separable pass from moments of functions that every channel shares.

With a linear loss, the projected amplitudes a_kc and every other colour value the same in all channels, the
model is f_nc = f₀_n(θ) + Σ_k B_nk(θ) a_kc with f₀ and the basis B the same in every channel (a lobe evaluates a
channel from that channel's values alone). Every column of the Jacobian in channel c is then a combination of a
few functions of the samples that the channels share, scaled by the channel's weights w_nc:

    ∂r_c/∂a_kc = w_c B_k,        ∂r_c/∂θ_q = w_c (∂f₀/∂θ_q + Σ_k a_kc ∂B_k/∂θ_q),

so with E ``(N, L)`` the functions that are not zero by construction (f₀ where some lobe adds to it, each B_k,
and each ∂f₀/∂θ_q and ∂B_k/∂θ_q whose lobe reads θ_q), the compiled pass forms per channel the moments

    S_c = Eᵀ diag(w_c²) E ``(L, L)``,   g_c = Eᵀ (w_c r_c) ``(L,)``,   rᵀr per channel,

and the host maps them to the free scalars with a coefficient matrix V_c ``(L, P)`` (amplitudes of the point):
JᵀJ = Σ_c V_cᵀ S_c V_c and Jᵀr = Σ_c V_cᵀ g_c. The residuals themselves are formed on the device (no cancellation
in the cost). On a CPU the pass and its host sums take less time than
`brdffit.fitting.normal_equations.accumulate`'s, whose (C, Q + 1, N) tangents leave the cache.

The default solver's passes in a `fit_many` batch use it (`brdffit.fitting.marquardt`), but for the answers'
sums on the whole data, which need the residuals themselves (the sandwich covariance's meat, the metric sums):
those come from `accumulate`. `tests/test_moments.py` holds every lobe's moments to `accumulate`'s sums, also with
a fixed amplitude beside a free one and with padded samples.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .losses import get_loss
from .normal_equations import NormalEquations, shape_key, timed_first_calls
from .problem import FitData, Problem
from ..programs import Program
from .separable import adds_to_offset, channel_grams, one_channel_basis, same_in_every_channel, weights

__all__ = ["applies", "moment_sums"]


def applies(problem: Problem, fixed: dict) -> bool:
    """Whether a problem's passes can be formed from shared moments: a separable problem with a linear loss and
    no robust rewrite, amplitudes to project, no free colour parameter other than them, and the fixed colour
    values (``fixed``: name -> host array, leading axes allowed) the same in every channel.

    Arguments:
        problem: the `Problem`.
        fixed: the fixed parameters' values (`FitData.fixed` of the pieces).
    """
    if not (problem.separable and problem.linear and problem.robust is None and get_loss(problem.loss).linear):
        return False
    if any(problem.specs[name].colour for name in problem.outer):
        return False
    return same_in_every_channel(problem, fixed)


@functools.lru_cache(maxsize=64)
def _columns(problem: Problem) -> tuple:
    """The functions E of the module doc as indices ``t * (1 + K) + k`` into the full table of value (t = 0) and
    derivatives (t = q + 1 for outer name q) of f₀ (k = 0) and the amplitudes' basis (k = 1..K), keeping those
    that are not zero by construction."""
    layout, names, outer = problem.layout, problem.linear, problem.outer
    reads = [{slot.name for slot in layout.lobe_slots(j)} for j in range(len(problem.lobes))]
    owner = {name: next(j for j, read in enumerate(reads) if name in read) for name in names}
    offset = [j for j in range(len(problem.lobes)) if adds_to_offset(problem, j, names)]
    width = 1 + len(names)
    columns = [k for k in range(width) if k or offset]
    for q, name in enumerate(outer):
        if any(name in reads[j] for j in offset):
            columns.append((q + 1) * width)
        columns.extend((q + 1) * width + k + 1 for k, a in enumerate(names) if name in reads[owner[a]])
    return tuple(columns)


def _moments(problem: Problem, columns: tuple, tree: dict, data: FitData):
    """``(S (L, L, C), g (L, C), channel costs (C,))`` of one point on one material's data (the module doc)."""
    names, outer = problem.linear, problem.outer
    params = dict(data.fixed, **tree)

    def functions(shape):
        f0, basis = one_channel_basis(problem, dict(params, **shape), names, data)
        return jnp.concatenate([f0[:, None], basis], axis=1)  # (N, 1 + K)

    at = {name: params[name] for name in outer}
    seeds = {name: jnp.stack([jnp.ones_like(value) if name == q else jnp.zeros_like(value) for q in outer])
             for name, value in at.items()}
    value, derivatives = jax.vmap(lambda seed: jax.jvp(functions, (at,), (seed,)), out_axes=(None, 0))(seeds)
    n = value.shape[0]
    table = jnp.concatenate([value[None], derivatives]).transpose(1, 0, 2).reshape(n, -1)
    e = table[:, np.asarray(columns)]  # (N, L)
    amplitudes = jnp.stack([params[name] for name in names], axis=-1)  # (C, K)
    w = weights(problem, data)  # (N, C), 0 where a value is missing
    r = w * (value[:, :1] + value[:, 1:] @ amplitudes.T - data.values)
    return channel_grams(e, w * w), e.T @ (w * r), jnp.sum(r * r, axis=0)


@functools.lru_cache(maxsize=64)
def _program(structure: Problem):
    """The compiled moments of ``(trees (W, S) + shape, data with a material axis, materials (W,))``: row i of
    ``trees`` on material ``materials[i]``, gathered on the device (as `pass_program`'s gathered pass); the first
    call of each shape adds its seconds to `compile_seconds`."""
    columns = _columns(structure)
    per_point = jax.vmap(jax.vmap(lambda tree, data: _moments(structure, columns, tree, data), in_axes=(0, None)),
                         in_axes=(0, 0))
    program = Program(lambda trees, data, index: per_point(trees, jax.tree_util.tree_map(lambda a: a[index], data)),
                      f"moments {structure!r}")
    return timed_first_calls(program, lambda trees, data, index: shape_key(trees, data))


def _coefficients(problem: Problem, trees: dict) -> np.ndarray:
    """V ``(W, S, C, L, P)``: each free scalar's Jacobian column in channel c as a combination of the functions E
    (the module doc), at the points ``trees`` (host values)."""
    layout, names, outer = problem.layout, problem.linear, problem.outer
    columns = {index: i for i, index in enumerate(_columns(problem))}
    width, channels = 1 + len(names), problem.channels
    offsets = layout.offsets(problem.free)
    points = np.shape(trees[problem.free[0]])[:2]
    v = np.zeros(points + (channels, len(columns), sum(layout[name].size for name in problem.free)))
    for k, name in enumerate(names):
        for c in range(channels):
            v[..., c, columns[k + 1], offsets[name].start + c] = 1.0
    for q, name in enumerate(outer):
        at = offsets[name].start
        if (q + 1) * width in columns:
            v[..., columns[(q + 1) * width], at] = 1.0
        for k, a in enumerate(names):
            if (q + 1) * width + k + 1 in columns:
                v[..., columns[(q + 1) * width + k + 1], at] = np.asarray(trees[a], dtype=float)
    return v


def moment_sums(problem: Problem, trees: dict, pieces: list[FitData], materials) -> NormalEquations:
    """JᵀJ, Jᵀr, rᵀr and the per-channel rᵀr of every point of a batch from the shared moments (`applies` must
    hold), without the meat and the metric sums.

    Arguments:
        problem: the `Problem`.
        trees: free name -> physical values ``(W, S) + shape``.
        pieces: the data of the batch's materials (leading material axis), whole or in chunks.
        materials: integer indices ``(W,)``: row i of ``trees`` is evaluated on material ``materials[i]``.

    Returns:
        The `NormalEquations` (``meat`` and ``metric_sums`` None), fields with leading axes ``(W, S)``.
    """
    program = _program(problem.structure)
    index = np.asarray(materials, dtype=np.int32)
    s = g = cost = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for piece in pieces:
            out = program(trees, piece, index)
            s, g, cost = s + np.asarray(out[0]), g + np.asarray(out[1]), cost + np.asarray(out[2])
        v = _coefficients(problem, trees)
        jtj = np.einsum("...clp,...lmc,...cmq->...pq", v, s, v)
        jtr = np.einsum("...clp,...lc->...p", v, g)
    return NormalEquations(jtj=jtj, jtr=jtr, cost=np.sum(cost, axis=-1), meat=None, channel_cost=cost,
                           metric_sums=None)
