"""The least-squares problem a fit solves: its static structure, its data arrays and its residuals.

`Problem` is the hashable static part (lobes, which parameters are free, loss, solver, step limit, whether the
amplitudes are projected out); `FitData` holds the arrays.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..arrays import host_arrays, on_device, on_host, to_device
from ..geometry import LocalPair, spherical_to_vector
from ..models.layout import Layout, layout
from ..models.model import Model, evaluate_pair
from ..params import ParamTable
from .losses import get_loss, robust_residuals
from ..programs import Program

__all__ = ["Problem", "FitData", "make_fit_data", "bucket", "BUCKET_CHUNK", "physical_params", "residual_fn", "residuals_at", "stack_data",
           "sample_pieces", "take_materials", "take_samples",
           "flatten_free", "PER_SAMPLE"]

# The fields of a `FitData` with a sample axis (the others hold one value per material).
PER_SAMPLE = ("pair", "values", "mask", "cos_i", "sqrt_weight", "sigma")


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """Static description of a fit (hashable, so it can key the compile cache).

    Attributes:
        lobes: the lobes of the model.
        channels: number of channels.
        free: names of the fitted parameters, in model order; all others are held at values in `FitData.fixed`.
        loss: residual definition (a name in `brdffit.fitting.losses.LOSSES`).
        robust: None, ``"huber"`` or ``"cauchy"``.
        solver: the solver object (`brdffit.fitting.solvers.make_solver`).
        max_steps: the solver's step limit.
        separable: True to solve the free linear amplitudes exactly for each value of the other parameters
            (`brdffit.fitting.separable`); the solver then sees only `outer`.
    """

    lobes: tuple
    channels: int
    free: tuple
    loss: str
    robust: str | None
    solver: Any
    max_steps: int
    separable: bool = False

    def _key(self) -> tuple:
        # Solver objects may hold JAX arrays (GaussNewton's learning rate), which are unhashable: key them by
        # their tree structure and leaf values instead.
        leaves, treedef = jax.tree_util.tree_flatten(self.solver)
        solver_key = (treedef, tuple(np.asarray(leaf).tobytes() if hasattr(leaf, "shape") else leaf
                                     for leaf in leaves))
        return (self.lobes, self.channels, self.free, self.loss, self.robust, solver_key, self.max_steps,
                self.separable)

    def __hash__(self) -> int:
        return hash(self._key())

    def __eq__(self, other) -> bool:
        return isinstance(other, Problem) and self._key() == other._key()

    @property
    def structure(self) -> "Problem":
        """This problem without its solver and step limit: what a compiled evaluation of its residuals depends on
        (the key of the compiled passes and of the search's scoring, shared by every solver and stage)."""
        return dataclasses.replace(self, solver=None, max_steps=0)

    @functools.cached_property
    def layout(self) -> Layout:
        """The model's parameter layout (`brdffit.models.layout.layout`, kept on the problem: a solve asks for it
        thousands of times, and each lookup of the shared cache hashes the lobes)."""
        return layout(self.lobes, self.channels)

    @property
    def specs(self) -> ParamTable:
        """The model's parameter declarations under their model-level names."""
        return self.layout.specs

    @property
    def linear(self) -> tuple:
        """The free amplitudes solved by projection (empty unless `separable`)."""
        return self.layout.linear(self.free) if self.separable else ()

    @property
    def outer(self) -> tuple:
        """The free parameters the solver sees: all free ones but the projected amplitudes."""
        linear = set(self.linear)
        return tuple(name for name in self.free if name not in linear)

    def model(self, params: dict) -> Model:
        """A `Model` of this problem's lobes with the given parameter values."""
        return Model(params=params, lobes=self.lobes, channels=self.channels)


class FitData(NamedTuple):
    """The arrays of a fit (a pytree; a leading batch axis is added by `stack_data` for `fit_many`).

    Fields:
        pair: the `LocalPair` of the samples' directions (computed once: it does not depend on the parameters).
        values: ``(N, C)`` data with missing samples set to 0.
        mask: ``(N, C)`` True where the sample is valid.
        cos_i: ``(N,)``.
        sqrt_weight: ``(N,)`` square roots of the quadrature weights (ones when the data have none).
        sigma: ``(N, C)`` per-sample σ (ones where unknown).
        eps: ``(C,)`` the relative loss's ε.
        robust_scale: scalar scale of the robust loss (unused without one).
        fixed: name -> value of every parameter that is not fitted.
    """

    pair: LocalPair
    values: Any
    mask: Any
    cos_i: Any
    sqrt_weight: Any
    sigma: Any
    eps: Any
    robust_scale: Any
    fixed: dict


# Sample counts are padded to one of a few sizes (`bucket`) so that files of different sizes share compiled
# programs, in one process and through JAX's persistent cache: 2^k and 3·2^(k−1) samples from 512 up to one chunk
# of the passes (at most half as many again, a quarter on average), whole chunks beyond.
BUCKET_CHUNK = 65536
_BUCKETS = sorted(size for k in range(9, 17) for size in (2 ** k, 3 * 2 ** (k - 1)) if 512 <= size <= BUCKET_CHUNK)


def bucket(n: int) -> int:
    """The padded sample count of ``n`` samples (see `BUCKET_CHUNK`)."""
    if n > BUCKET_CHUNK:
        return -(-n // BUCKET_CHUNK) * BUCKET_CHUNK
    return next(size for size in _BUCKETS if size >= n)


def make_fit_data(measurements, fixed: dict, eps, robust_scale: float = 1.0, pad: bool = False,
                  device: bool = True) -> FitData:
    """Build `FitData` from `brdffit.Measurements`.

    Arguments:
        measurements: the data.
        fixed: name -> value of the parameters held fixed.
        eps: ``(C,)`` the relative loss's ε.
        robust_scale: scale of the robust loss.
        pad: append missing samples (at normal incidence and exitance, masked) up to `bucket` of the count.
        device: put the arrays on the device; False leaves them NumPy arrays (`brdffit.arrays.host_arrays`) for a
            pipeline that cuts and stacks them first (`take_samples`, `stack_data`, `sample_pieces`: a `fit_many`
            would otherwise move each material's arrays to the device and back before stacking them).

    Returns:
        The `FitData`.
    """
    n = measurements.n
    extra = bucket(n) - n if pad else 0

    def host(a, fill=0.0):
        if a is None:
            return None
        a = np.asarray(a, dtype=float)
        return np.concatenate([a, np.full((extra,) + a.shape[1:], fill)]) if extra else a

    pair, values, mask, cos_i, sqrt_weight, sigma = _sample_fields(
        host(measurements.values, np.nan), *(host(getattr(measurements, k))
                                             for k in ("theta_i", "phi_i", "theta_o", "phi_o")),
        host(measurements.weights, 1.0), host(measurements.sigma, 1.0))
    as_array = lambda a: np.asarray(a, dtype=float)  # noqa: E731
    data = FitData(
        pair=pair, values=values, mask=mask, cos_i=cos_i, sqrt_weight=sqrt_weight, sigma=sigma, eps=as_array(eps),
        robust_scale=as_array(robust_scale), fixed={k: as_array(v) for k, v in fixed.items()},
    )
    return on_device(data) if device else host_arrays(data)


# The data's own arrays (their fields, subsamples, stacks, pieces) are computed on the host in NumPy and moved to
# the device once: they do not depend on the model, so compiled programs would only add their compilations to a
# first fit (in a new process XLA compiles even an addition), and NumPy does each in milliseconds
# (docs/benchmarks.md).
def _sample_fields(values, theta_i, phi_i, theta_o, phi_o, weights, sigma):
    """The per-sample fields of `FitData` (NumPy, on the host): the `LocalPair`, the values with missing ones set
    to 0, the mask, cosθi clamped at 0, √weights (ones when None) and σ (ones where unknown or not positive)."""
    wi, wo = spherical_to_vector(theta_i, phi_i, xp=np), spherical_to_vector(theta_o, phi_o, xp=np)
    mask = np.isfinite(values)
    sigma = np.ones_like(values) if sigma is None else np.where(np.isfinite(sigma) & (sigma > 0), sigma, 1.0)
    sqrt_weight = np.ones_like(theta_i) if weights is None else np.sqrt(weights)
    return (LocalPair.from_dirs(wi, wo, xp=np), np.where(mask, values, 0.0), mask, np.maximum(wi[:, 2], 0.0),
            sqrt_weight, sigma)


def _per_sample(data: FitData) -> dict:
    """The per-sample fields of ``data``, which a subsample cuts (the others, ε, the robust scale and the fixed
    values, are a few numbers a material)."""
    return {k: getattr(data, k) for k in PER_SAMPLE}


def take_samples(data: FitData, rows) -> FitData:
    """The samples ``rows`` (sorted indices into one material's ``data``) as `FitData` of `bucket` of their count
    samples, the padding masked: the `make_fit_data` of those rows of the measurements (``pad=True``), as NumPy
    arrays (``device=False``; `stack_data` moves them).

    Arguments:
        data: one material's `FitData` (no material axis).
        rows: integer indices of valid or padded samples of ``data``.

    Returns:
        The `FitData` of those samples.
    """
    rows = np.asarray(rows, dtype=np.intp)
    size = bucket(rows.size)
    valid = np.arange(size) < rows.size
    index = np.concatenate([rows, np.zeros(size - rows.size, np.intp)])
    fields = jax.tree_util.tree_map(lambda a: a[index], on_host(_per_sample(data)))
    mask = fields["mask"] & valid[:, None]
    return host_arrays(data._replace(**dict(fields, mask=mask, values=np.where(mask, fields["values"], 0.0))))


def stack_data(items: list[FitData]) -> FitData:
    """Stack equally shaped `FitData` along a new leading axis (for the vmapped `fit_many`; one item: an axis of
    1), as NumPy arrays: each call of a compiled program moves its arguments itself, in JAX's C++ dispatch, far
    cheaper than a ``jax.device_put`` (docs/fitting.md)."""
    return host_arrays(jax.tree_util.tree_map(lambda *xs: np.stack(xs), *on_host(list(items))))


def take_materials(data: FitData, materials) -> FitData:
    """The materials ``materials`` (integer indices, repeats allowed) of stacked ``data`` (`stack_data`), stacked
    in that order (NumPy arrays, as `stack_data` gives them)."""
    materials = np.asarray(materials, dtype=np.intp)
    return host_arrays(jax.tree_util.tree_map(lambda a: a[materials], on_host(data)))


def sample_pieces(data: FitData, size: int) -> list[FitData]:
    """Stacked ``data`` (`stack_data`: a leading material axis) in pieces of ``size`` samples, every material in
    each piece, as NumPy arrays (`stack_data`); the last piece is padded with masked samples so that every piece has
    the same shape (one compilation serves all). Data of at most ``size`` samples is one piece.

    Arguments:
        data: `FitData` with leading axes (materials, samples) on the per-sample fields.
        size: the samples of a piece.

    Returns:
        A list of `FitData`, each with the material axis of ``data``.
    """
    fields = on_host(data._asdict())
    n = fields["values"].shape[1]
    width = max(min(size, n), 1)

    def cut(a, start):  # samples start to start + width of a (axis 1), padded with zeros (masked)
        part = a[:, start:start + width]
        return np.concatenate([part, np.zeros((a.shape[0], width - part.shape[1]) + a.shape[2:], a.dtype)], axis=1)

    return [FitData(**host_arrays(dict(fields, **{k: jax.tree_util.tree_map(lambda a: cut(a, start), fields[k])
                                                 for k in PER_SAMPLE})))
            for start in range(0, max(n, 1), width)]


def flatten_free(problem: Problem, tree: dict, names=None):
    """Flatten the free parameters (or ``names``) of ``tree`` in model order (`Layout.flatten`).

    Arguments:
        problem: the `Problem`.
        tree: name -> array for (at least) every flattened name.
        names: the names to flatten; default ``problem.free``.

    Returns:
        ``(flat, unravel)``: the 1-d JAX array and the function that maps such an array back to a dict.
    """
    names = problem.free if names is None else tuple(names)
    flat = problem.layout.flatten(tree, names, xp=jnp)
    return flat, lambda theta: problem.layout.unflatten(theta, names, xp=jnp)


def physical_params(problem: Problem, y: dict, fixed: dict) -> dict:
    """Map unconstrained solver variables to physical parameter values and merge the fixed ones.

    Arguments:
        problem: the `Problem`.
        y: name -> unconstrained value of the parameters the solver moves.
        fixed: name -> physical value of the others (fixed ones, and projected amplitudes when known).

    Returns:
        name -> physical value for every parameter of the model, in model order.
    """
    return {spec.name: spec.from_unconstrained(y[spec.name]) if spec.name in y else fixed[spec.name]
            for spec in problem.specs}


def residual_fn(problem: Problem, params: dict, data: FitData):
    """Residuals ``(N, C)`` of the model with physical ``params`` against ``data``; missing samples give 0."""
    return residuals_of(problem, evaluate_pair(problem.model(params), data.pair), data)


# `residual_fn` compiled (the problem is static): for evaluations outside a solve, which would otherwise run
# operation by operation, each compiled on its own for every new model (seconds per selection candidate).
_residuals = Program(residual_fn, "residuals", static_argnums=(0,))


def residuals_at(problem: Problem, params: dict, data: FitData):
    """`residual_fn` compiled, one program per problem structure (`Problem.structure`: every solver and stage
    shares it) and data shape. ``params`` may hold host values (NumPy arrays, numbers): they are moved to the
    device here, once per call, as `brdffit.arrays.to_device` gives them."""
    return _residuals(problem.structure, {k: to_device(v) for k, v in params.items()}, data)


def residuals_of(problem: Problem, f_model, data: FitData):
    """Residuals ``(N, C)`` of model values ``f_model`` against ``data`` (loss, robust rewrite, mask)."""
    r = get_loss(problem.loss).residuals(f_model, data.values, data.cos_i, data.sqrt_weight, data.sigma, data.eps)
    r = robust_residuals(problem.robust, r, data.robust_scale)
    return jnp.where(data.mask, r, 0.0)
