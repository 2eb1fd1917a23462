"""Normal matrices of a fit's residual Jacobian: JᵀJ, Jᵀr, rᵀr and Jᵀ diag(r²) J, accumulated over chunks.

J is taken with respect to the free physical parameters. Used by the full-data refinement
(`brdffit.fitting.refine`, which maps the outer parameters' columns to the solver's unconstrained variables by the
chain rule) and by the covariance of a fit (`brdffit.fitting.uncertainty`).

Colour parameters hold one value per channel, and channel c of the residuals depends on channel c of a colour
parameter only (a model evaluates its channels independently; only shape parameters are shared). One
forward-mode tangent per parameter *name*, seeded with ones in every channel, therefore yields all of that
parameter's Jacobian columns at once: the tangent's channel c is ∂r[:, c]/∂p[c]. A fit with Q free names and
P free scalars needs Q Jacobian-vector products instead of P (Lambert + Cook-Torrance in RGB: 3 instead of 7).
`accumulate` forms the per-channel sums S[q, s, c] = Σ_n t_q[n, c] t_s[n, c] chunk by chunk and expands them
into the P × P matrices. `tests/test_normal_equations.py` checks the result against
``jax.jacfwd`` for every lobe.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .problem import FitData, Problem, chunk_data, physical_params, residual_fn

__all__ = ["NormalEquations", "chunk_tangents", "chunks", "accumulate", "CHUNK_SAMPLES"]

CHUNK_SAMPLES = 65536


class NormalEquations(NamedTuple):
    """The sums `accumulate` returns, as NumPy float64, in `brdffit.problem.flatten_free` order.

    Fields:
        jtj: JᵀJ ``(P, P)``.
        jtr: Jᵀr ``(P,)``.
        cost: rᵀr.
        meat: Jᵀ diag(r²) J ``(P, P)`` (the sandwich covariance's middle).
        channel_cost: rᵀr of each channel ``(C,)``.
    """

    jtj: np.ndarray
    jtr: np.ndarray
    cost: float
    meat: np.ndarray
    channel_cost: np.ndarray


@functools.lru_cache(maxsize=64)
def chunk_tangents(problem: Problem):
    """The jitted tangents and residuals of one chunk, laid out for the per-channel Gram matrices.

    Arguments:
        problem: the `Problem`; the tangents are taken with respect to its free physical parameters (the other
            parameters come from ``data.fixed``).

    Returns:
        ``fn(tree, data) -> A`` with ``tree`` the free name -> value dict and ``A`` of shape ``(C, Q + 1, N)``:
        ``A[c, q]`` the tangent of free name q (in ``problem.free`` order) in channel c, ``A[c, Q]`` the
        residuals.
    """

    def fn(tree: dict, data: FitData):
        def r(values):
            return residual_fn(problem, physical_params(problem, {}, dict(data.fixed, **values)), data)

        rows = []
        for name in problem.free:
            seed = {k: (jnp.ones_like(v) if k == name else jnp.zeros_like(v)) for k, v in tree.items()}
            rows.append(jax.jvp(r, (tree,), (seed,))[1])
        rows.append(r(tree))
        return jnp.transpose(jnp.stack(rows), (2, 0, 1))

    return jax.jit(fn)


def chunks(data: FitData, size: int = CHUNK_SAMPLES) -> list[FitData]:
    """``data`` in equally shaped chunks of ``size`` samples (bounds the memory of the tangents); split once and
    reuse the list when accumulating repeatedly."""
    return chunk_data(data, size)


def accumulate(problem: Problem, tree: dict, pieces: list[FitData]) -> NormalEquations:
    """JᵀJ, Jᵀr, rᵀr, Jᵀ diag(r²) J and the per-channel rᵀr over all of the data.

    Arguments:
        problem: the `Problem`.
        tree: free name -> physical value, no batch axis.
        pieces: the `FitData` in chunks (`chunks`).

    Returns:
        The `NormalEquations`.

    Raises:
        ValueError: a value of the wrong shape.
    """
    for name in problem.free:
        want = problem.layout[name].shape
        if np.shape(tree[name]) != want:
            raise ValueError(f"parameter {name!r} has shape {np.shape(tree[name])}; expected {want}")
    index, incidence = problem.layout.channel_incidence(problem.free)
    fn = chunk_tangents(problem)
    q = len(problem.free)
    gram, meat = 0.0, 0.0
    # A diverged solver (undamped Gauss-Newton far away) can overflow the products: inf/NaN then reach the
    # covariance as infinite standard errors, which is what they mean, without a warning per chunk.
    with np.errstate(over="ignore", invalid="ignore"):
        for piece in pieces:
            # The per-channel Gram matrices with BLAS on the host: measured 3x faster on the CPU than the same
            # reductions in XLA, and a (C, Q + 1, N) transfer per chunk on a GPU.
            a = np.asarray(fn(tree, piece))
            gram = gram + a @ a.transpose(0, 2, 1)  # (C, Q+1, Q+1): tangents and residuals
            weighted = a[:, :q] * a[:, q:]
            meat = meat + weighted @ weighted.transpose(0, 2, 1)
        both = incidence[:, None, :] * incidence[None, :, :]  # (P, P, C): channels shared by scalars i and j
        gram = np.moveaxis(np.asarray(gram), 0, -1)  # (Q+1, Q+1, C)
        meat = np.moveaxis(np.asarray(meat), 0, -1)

        def expand(sums):
            return np.sum(both * sums[index][:, index], axis=-1)

        jtr = np.sum(incidence * gram[index, q], axis=-1)
        return NormalEquations(jtj=expand(gram[:q, :q]), jtr=jtr, cost=float(np.sum(gram[q, q])),
                               meat=expand(meat), channel_cost=np.array(gram[q, q], dtype=float))
