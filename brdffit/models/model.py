"""The model: a sum of lobes with its parameter values, as a JAX pytree.

A `Model` can be passed straight into `jax.jit`, `jax.vmap` and `jax.grad`: its parameter values are the leaves,
the lobes and channel count are static structure. It is a frozen dataclass registered with JAX
(``jax.tree_util.register_dataclass``), not an equinox Module: equinox (and jaxtyping with it) took 0.15-0.2 s to
import at the start of every fit, and only an optimistix solver needs it.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..arrays import on_device, padded_columns, traced
from ..programs import Program
from ..geometry import LocalPair, spherical_to_vector
from ..params import ParamSpec, ParamTable
from .layout import Layout, layout

__all__ = ["Model", "evaluate", "evaluate_dirs", "evaluate_pair", "evaluation_program", "EVALUATION_ROWS"]


@functools.partial(jax.tree_util.register_dataclass, data_fields=["params"], meta_fields=["lobes", "channels"])
@dataclasses.dataclass(frozen=True, eq=False)
class Model:
    """A BRDF model: a sum of lobes and the values of their parameters.

    Build one with `brdffit.models.get`; evaluate it with `brdffit.evaluate` or `brdffit.evaluate_dirs`.

    Attributes:
        params: parameter name -> value (colour parameters ``(channels,)``, shape parameters scalars).
        lobes: the lobes of the sum (static).
        channels: number of channels (static).
    """

    params: dict
    lobes: tuple
    channels: int

    @property
    def spec(self) -> str:
        """The spec string of the sum, with non-default lobe options in brackets."""
        return "+".join(lobe.token() for lobe in self.lobes)

    @property
    def layout(self) -> Layout:
        """The parameter layout (model-level names, declarations, shapes, roles), computed once per structure."""
        return layout(self.lobes, self.channels)

    @property
    def names_by_lobe(self) -> tuple[tuple[str, ...], ...]:
        """For each lobe, the model-level names of its parameters."""
        return tuple(tuple(slot.name for slot in self.layout.lobe_slots(j)) for j in range(len(self.lobes)))

    @property
    def param_specs(self) -> ParamTable:
        """The parameter declarations under their model-level names, in order."""
        return self.layout.specs

    @property
    def reciprocal(self) -> bool:
        """True if every lobe of the sum is reciprocal by construction."""
        return all(lobe.reciprocal for lobe in self.lobes)

    def replace(self, **params) -> "Model":
        """Return a new model with some parameter values replaced.

        Arguments:
            **params: name -> value; a colour parameter accepts a scalar (all channels) or ``(channels,)``.

        Returns:
            The new `Model`; the original is unchanged.

        Raises:
            KeyError: for an unknown name. ValueError: for a value of the wrong shape.
        """
        table = self.param_specs
        new = {name: coerce_value(table[name], value, self.channels) for name, value in params.items()}
        return Model(params=dict(self.params, **on_device(new)), lobes=self.lobes, channels=self.channels)

    def __call__(self, wi, wo):
        """Same as `evaluate_dirs(self, wi, wo)`."""
        return evaluate_dirs(self, wi, wo)


def coerce_value(spec: ParamSpec, value, channels: int):
    """Turn a user-given value into the stored shape of ``spec``, or raise a ValueError that names it. A host value
    is shaped in NumPy and stays on the host: the caller moves a model's values with one `brdffit.arrays.on_device`
    (no compiled program; a transfer per value cost a sizeable share of a `fit_many`'s results); a traced one stays
    traced. A device value already of the stored shape and of JAX's float type stays as it is (the pipeline
    moves a batch's answers with one `on_device`)."""
    if isinstance(value, jax.Array) and not traced(value) and value.dtype == jax.dtypes.canonicalize_dtype(float) \
            and value.shape == ((channels,) if spec.colour else ()):
        return value
    on_tracer = traced(value)
    xp = jnp if on_tracer else np
    value = xp.asarray(value, dtype=float)
    if spec.colour:
        if value.ndim == 0:
            value = xp.full((channels,), value)
        elif value.shape != (channels,):
            raise ValueError(
                f"colour parameter {spec.name!r} needs a scalar or shape ({channels},), got shape {value.shape}"
            )
    elif value.ndim != 0:
        raise ValueError(f"shape parameter {spec.name!r} is shared by all channels and needs a scalar, "
                         f"got shape {value.shape}")
    return value


# Host calls of `evaluate_dirs` and `evaluate` run one compiled program per model structure (`_evaluate_rows`,
# instead of one per primitive as JAX does when it runs them eagerly: dozens per lobe), on `EVALUATION_ROWS` pairs a
# call, the last call padded: every caller (a report's figures, scenes and tables, the plausibility checks, the
# readers' and exports' evaluations) then shares that one compilation, where a program per input shape compiled
# once for each of them on the critical path of a first report. As a `Program` it is also kept on disk where JAX's
# persistent cache is on, so a warm process loads it without tracing. Called on traced values (inside ``jax.jit``,
# ``jax.grad``), they are the plain JAX expression.
EVALUATION_ROWS = 1 << 14


@Program
def _evaluate_rows(model: Model, wi, wo):
    """f_r of ``model`` at the pairs of unit vectors ``wi``, ``wo`` ``(N, 3)``: ``(N, channels)``."""
    return evaluate_pair(model, LocalPair.from_dirs(wi, wo))


def evaluate_dirs(model: Model, wi, wo):
    """Evaluate a model for pairs of unit direction vectors.

    Arguments:
        model: the `Model`.
        wi: directions to the light, shape ``(..., 3)``, unit length, local frame (z = normal).
        wo: directions to the detector, broadcastable with ``wi``.

    Returns:
        f_r in 1/sr without the cosine factor, shape ``broadcast(...) + (channels,)`` (a NumPy float64 array, or a
        JAX array when called on traced values); zero unless both directions lie strictly above the horizon.
    """
    if traced((model, wi, wo)):
        return evaluate_pair(model, LocalPair.from_dirs(wi, wo))
    wi, wo = np.broadcast_arrays(np.asarray(wi, dtype=float), np.asarray(wo, dtype=float))
    (f,) = padded_columns(lambda *rows: _evaluate_rows(model, *rows), wi.reshape(-1, 3), wo.reshape(-1, 3),
                          chunk=EVALUATION_ROWS, least=EVALUATION_ROWS)
    return f.reshape(wi.shape[:-1] + (model.channels,))


def evaluation_program(model: Model):
    """``run(wi, wo)``: the compiled program that `evaluate_dirs` calls for ``model``, on `EVALUATION_ROWS` pairs of
    unit vectors ``(EVALUATION_ROWS, 3)`` already on the device, without `evaluate_dirs`' padding and copies on the
    host: the model's evaluation alone, for timing it."""
    return lambda wi, wo: _evaluate_rows(model, wi, wo)


def evaluate_pair(model: Model, pair: LocalPair):
    """Evaluate a model on precomputed direction quantities (fits compute the `LocalPair` of their data once).

    Arguments:
        model: the `Model`.
        pair: the `brdffit.geometry.LocalPair` of the directions.

    Returns:
        f_r in 1/sr, shape ``pair.above.shape + (channels,)``, zero below the horizon.
    """
    out_shape = pair.above.shape + (model.channels,)
    total = jnp.zeros(out_shape, dtype=pair.wi.dtype)
    for j, lobe in enumerate(model.lobes):
        total = total + jnp.broadcast_to(lobe(model.layout.local_params(model.params, j), pair), out_shape)
    return jnp.where(pair.above[..., None], total, 0.0)


def evaluate(model: Model, theta_i, phi_i, theta_o, phi_o):
    """Evaluate a model at spherical angles.

    Arguments:
        model: the `Model`.
        theta_i, phi_i: polar angle and azimuth of the direction to the light (radians).
        theta_o, phi_o: polar angle and azimuth of the direction to the detector (radians).
            All four broadcast against each other.

    Returns:
        f_r in 1/sr, shape ``broadcast(...) + (channels,)`` (``(N, channels)`` for 1-d inputs), as `evaluate_dirs`
        returns it.
    """
    xp = jnp if traced((model, theta_i, phi_i, theta_o, phi_o)) else np
    return evaluate_dirs(model, spherical_to_vector(theta_i, phi_i, xp=xp), spherical_to_vector(theta_o, phi_o, xp=xp))
