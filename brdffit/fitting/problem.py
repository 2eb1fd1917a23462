"""The least-squares problem a fit solves: its static structure, its data arrays and its residuals.

`Problem` is the hashable static part (lobes, which parameters are free, loss, solver, step limit, whether the
amplitudes are projected out); `FitData` holds the arrays.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..arrays import to_device
from ..geometry import LocalPair, spherical_to_vector
from ..models.layout import Layout, layout
from ..models.model import Model, evaluate_pair
from ..params import ParamTable
from .losses import get_loss, robust_residuals
from .programs import Program

__all__ = ["Problem", "FitData", "make_fit_data", "bucket", "BUCKET_CHUNK", "physical_params", "residual_fn", "residuals_at", "stack_data",
           "material_pieces", "take_materials", "take_samples", "chunk_data",
           "flatten_free"]

_PER_SAMPLE = ("pair", "values", "mask", "cos_i", "sqrt_weight", "sigma")


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

    @property
    def layout(self) -> Layout:
        """The model's parameter layout."""
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


def make_fit_data(measurements, fixed: dict, eps, robust_scale: float = 1.0, pad: bool = False) -> FitData:
    """Build `FitData` from `brdffit.Measurements`.

    Arguments:
        measurements: the data.
        fixed: name -> value of the parameters held fixed.
        eps: ``(C,)`` the relative loss's ε.
        robust_scale: scale of the robust loss.
        pad: append missing samples (at normal incidence and exitance, masked) up to `bucket` of the count.

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

    pair, values, mask, cos_i, sqrt_weight, sigma = _sample_arrays(
        host(measurements.values, np.nan), *(host(getattr(measurements, k))
                                             for k in ("theta_i", "phi_i", "theta_o", "phi_o")),
        host(measurements.weights, 1.0), host(measurements.sigma, 1.0))
    as_array = lambda a: to_device(a, dtype=float)  # noqa: E731
    return FitData(
        pair=pair, values=values, mask=mask, cos_i=cos_i, sqrt_weight=sqrt_weight, sigma=sigma, eps=as_array(eps),
        robust_scale=as_array(robust_scale), fixed={k: as_array(v) for k, v in fixed.items()},
    )


def _sample_fields(values, theta_i, phi_i, theta_o, phi_o, weights, sigma):
    """The per-sample fields of `FitData` in one compiled program: the `LocalPair`, the values with missing ones
    set to 0, the mask, cosθi clamped at 0, √weights (ones when None) and σ (ones where unknown or not positive)."""
    # The barrier makes XLA store the two direction arrays: without it the CPU compiler fused the sines and cosines
    # into every consumer and computed them several times over (twice the time on a MERL-size table).
    wi, wo = jax.lax.optimization_barrier((spherical_to_vector(theta_i, phi_i), spherical_to_vector(theta_o, phi_o)))
    mask = jnp.isfinite(values)
    sigma = jnp.ones_like(values) if sigma is None else jnp.where(jnp.isfinite(sigma) & (sigma > 0), sigma, 1.0)
    sqrt_weight = jnp.ones_like(theta_i) if weights is None else jnp.sqrt(weights)
    return (LocalPair.from_dirs(wi, wo), jnp.where(mask, values, 0.0), mask, jnp.maximum(wi[:, 2], 0.0),
            sqrt_weight, sigma)


_sample_arrays = Program(_sample_fields, "sample arrays")


def _per_sample(data: FitData) -> dict:
    """The per-sample fields of ``data``: the programs that cut and gather samples take only these, so that one
    compilation serves every model (the other fields' structure, ``fixed``, differs between models)."""
    return {k: getattr(data, k) for k in _PER_SAMPLE}


def _shared(data: FitData, index) -> dict:
    """The other fields (ε, the robust scale, the fixed values: a few numbers a material) indexed on the host."""
    return {k: jax.tree_util.tree_map(lambda a: to_device(np.asarray(a)[index]), getattr(data, k))
            for k in data._fields if k not in _PER_SAMPLE}


def _samples(fields: dict, rows, valid):
    fields = jax.tree_util.tree_map(lambda a: a[rows], fields)
    mask = fields["mask"] & valid[:, None]
    return dict(fields, mask=mask, values=jnp.where(mask, fields["values"], 0.0))


# One gather per pair of sizes: a subsample's fields computed anew (`make_fit_data`) compiled the sample fields
# once more for each subsample size, 0.2-0.3 s each in a first fit (issue 15).
_take_samples = Program(_samples, "take samples")


def take_samples(data: FitData, rows) -> FitData:
    """The samples ``rows`` (sorted indices into one material's ``data``) as `FitData` of `bucket` of their count
    samples, the padding masked: the `make_fit_data` of those rows of the measurements (``pad=True``).

    Arguments:
        data: one material's `FitData` (no material axis).
        rows: integer indices of valid or padded samples of ``data``.

    Returns:
        The `FitData` of those samples.
    """
    rows = np.asarray(rows, dtype=np.int32)
    size = bucket(rows.size)
    valid = np.arange(size) < rows.size
    return data._replace(**_take_samples(_per_sample(data), to_device(
        np.concatenate([rows, np.zeros(size - rows.size, np.int32)])), to_device(valid)))


def _stacked(items: list):
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *items)


# One compiled program per count and shapes: stacked eagerly, each field compiled a program of its own (fourteen in
# a first fit, 0.3 s; see `brdffit.arrays`).
_stack = Program(_stacked, "stack data")


def stack_data(items: list[FitData]) -> FitData:
    """Stack equally shaped `FitData` along a new leading axis (for the vmapped `fit_many`; one item: an axis of
    1)."""
    return _stack(list(items))


def _take(fields: dict, materials):
    return jax.tree_util.tree_map(lambda a: a[materials], fields)


# One compiled program per data shape and count: eager slicing dispatched one operation per array (~4 ms a
# material, a tenth of a fit_many material's time), and one program returning every material took 19 s to compile
# for 150 materials.
_take_materials = Program(_take, "take materials")


def take_materials(data: FitData, materials) -> FitData:
    """The materials ``materials`` (integer indices, repeats allowed) of stacked ``data`` (`stack_data`), stacked
    in that order."""
    materials = np.asarray(materials, dtype=np.int32)
    return FitData(**_take_materials(_per_sample(data), to_device(materials)), **_shared(data, materials))


def _piece(fields: dict, material, start, size: int) -> dict:
    n = fields["values"].shape[1]
    pad = -n % size

    def cut(a):
        a = a[material]
        if pad:
            a = jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)])
        return jax.lax.dynamic_slice_in_dim(a, start, size)[None]

    return jax.tree_util.tree_map(cut, fields)


# One small compiled program per data shape and piece size, called once per piece (one program returning every
# piece compiled in 0.37 s for 8 pieces; see also `_take_materials`).
_take_piece = Program(_piece, "data piece", static_argnums=(3,))


def material_pieces(data: FitData, size: int) -> list[list[FitData]]:
    """For each material of stacked ``data`` (`stack_data`), its samples in pieces of ``size`` (`chunk_data`:
    a leading material axis of 1, the last piece padded with masked samples; at most ``size`` samples: one)."""
    materials, n = data.values.shape[:2]
    size, fields = min(size, n), _per_sample(data)
    out = []
    for m in range(materials):
        shared, material = _shared(data, [m]), to_device(np.int32(m))
        out.append([FitData(**_take_piece(fields, material, to_device(np.int32(start)), size), **shared)
                    for start in range(0, n, size)])
    return out


def chunk_data(data: FitData, size: int):
    """Split one material's ``data`` into `FitData` pieces of ``size`` samples, each with a leading material axis
    of 1 (the layout of `stack_data`); the last is padded with masked samples so that every piece has the same
    shape (one compilation serves all). Data of at most ``size`` samples is one piece.

    Returns:
        A list of `FitData`.
    """
    return [FitData(**piece) for piece in _split(data._asdict(), size)]


def _pieces(fields: dict, size: int) -> list:
    # One compiled program cuts and stacks every piece (eager slicing took 0.1 s on a MERL-size table, eager
    # stacking 0.4 s).
    n = fields["values"].shape[0]
    pieces = max(-(-n // size), 1)
    pad = pieces * size - n if n > size else 0

    def padded(a):
        return jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)]) if pad else a

    per_sample = {k: jax.tree_util.tree_map(padded, fields[k]) for k in _PER_SAMPLE}
    shared = {k: jax.tree_util.tree_map(lambda a: a[None], v) for k, v in fields.items() if k not in _PER_SAMPLE}
    width = min(size, n)
    return [dict(shared, **jax.tree_util.tree_map(lambda a, start=start: a[None, start:start + width], per_sample))
            for start in range(0, pieces * width, width)]


_split = Program(_pieces, "data pieces", static_argnums=(1,))


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
    shares it) and data shape."""
    return _residuals(problem.structure, params, data)


def residuals_of(problem: Problem, f_model, data: FitData):
    """Residuals ``(N, C)`` of model values ``f_model`` against ``data`` (loss, robust rewrite, mask)."""
    r = get_loss(problem.loss).residuals(f_model, data.values, data.cos_i, data.sqrt_weight, data.sigma, data.eps)
    r = robust_residuals(problem.robust, r, data.robust_scale)
    return jnp.where(data.mask, r, 0.0)
