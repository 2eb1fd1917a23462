"""Parameter declarations and the smooth transforms that keep fitted parameters in bounds.

A model declares each parameter once, as a `ParamSpec`. Everything else that needs to know about a parameter
(defaults, bounds, the unconstrained transform used by the least-squares solver, priors, CLI help, HDF5 keys,
documentation tables, report labels) is derived from that declaration.

optimistix has no box constraints for least squares, so a bounded parameter p is fitted through an unconstrained
variable u (the STYLE guide's "bounds through transforms"). The transforms are MINUIT's (James & Roos, MINUIT
User's Guide, CERN D506, section 1.3.1; also lmfit's bounds):

- lower and upper finite:  p = lower + (upper − lower) (1 + sin u)/2
- lower finite only:       p = lower − 1 + √(u² + 1)
- upper finite only:       p = upper + 1 − √(u² + 1)
- neither:                 p = u

Each reaches its bound at a finite u, where dp/du = 0: an optimum on a bound is then an ordinary stationary point
of the solver's problem, which it converges to, instead of a limit at u -> ±∞ that a logistic or softplus
transform approaches without end (the step test never passes, and the fit ends at ``max-steps``). A solve must
therefore not *start* on a bound (dp/du = 0 there): starts are moved inside first
(`brdffit.fitting.search.interior`).
"""

from __future__ import annotations

import dataclasses
import math

from ._lazy import module

# Loaded on first use: the registry (`brdffit models`) needs neither.
np = module("numpy")
jnp = module("jax.numpy")
arrays = module("brdffit.arrays")

__all__ = ["ParamSpec", "ParamTable", "to_unconstrained", "from_unconstrained", "transform_slope", "at_bound",
           "bound_margin"]

@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """The one declaration of a model parameter.

    Arguments:
        name: parameter name as the model exposes it (e.g. ``"rho_d"``).
        default: default value (the same for every channel of a colour parameter).
        lower: lower bound (``-inf`` for none). Bounds are open for the transforms.
        upper: upper bound (``inf`` for none).
        colour: True for a colour parameter (one value per channel), False for a shape parameter shared by all
            channels.
        unit: unit of the parameter ("1", "1/sr", "rad", ...).
        doc: one-line meaning.
        scale: True for a scale parameter (roughness, exponent, amplitude): priors are log-uniform.
        fixed: True if the parameter is held at its value unless a fit frees it explicitly.
        linear: True for an amplitude that the BRDF is affine in, channel by channel (f = f₀ + p·B with f₀ and B
            independent of p): a fit solves it exactly by bounded linear least squares for each value of the
            other parameters (variable projection, `brdffit.fitting.separable`). Only colour parameters can be
            linear (each channel's amplitude acts on that channel alone); `tests/test_models.py` checks every
            declaration numerically.
    """

    name: str
    default: float
    lower: float = -math.inf
    upper: float = math.inf
    colour: bool = False
    unit: str = "1"
    doc: str = ""
    scale: bool = False
    fixed: bool = False
    linear: bool = False

    def __post_init__(self):
        if not self.lower < self.upper:
            raise ValueError(f"parameter {self.name!r}: lower bound {self.lower} is not below upper {self.upper}")
        if not self.lower <= self.default <= self.upper:
            raise ValueError(
                f"parameter {self.name!r}: default {self.default} outside [{self.lower}, {self.upper}]"
            )
        if self.linear and not self.colour:
            raise ValueError(f"parameter {self.name!r}: only a colour parameter can be a linear amplitude")

    @property
    def kind(self) -> str:
        """``"colour"`` or ``"shape"``."""
        return "colour" if self.colour else "shape"

    @property
    def role(self) -> str:
        """``"linear"`` (an amplitude solved exactly for given other parameters) or ``"nonlinear"``."""
        return "linear" if self.linear else "nonlinear"

    def renamed(self, name: str) -> "ParamSpec":
        """Return the same declaration under another name (used when lobes of a sum share a name)."""
        return dataclasses.replace(self, name=name)

    def initial(self, channels: int):
        """The default value with the parameter's shape: ``(channels,)`` for colour, scalar for shape."""
        return arrays.to_device(np.full((channels,) if self.colour else (), self.default, dtype=float))

    def to_unconstrained(self, value, xp=jnp):
        """Map a value within the bounds to the unconstrained fitting variable (inverse of `from_unconstrained`);
        ``xp`` is the array module (``numpy`` on the host, `jax.numpy` by default)."""
        return to_unconstrained(value, self.lower, self.upper, xp)

    def from_unconstrained(self, u, xp=jnp):
        """Map the unconstrained fitting variable to a value within the bounds (``xp`` as above)."""
        return from_unconstrained(u, self.lower, self.upper, xp)

    def transform_slope(self, u):
        """dp/du of `from_unconstrained` at ``u`` (NumPy)."""
        return transform_slope(u, self.lower, self.upper)


class ParamTable(tuple):
    """The parameter declarations of a model, in order; iterate for `ParamSpec`s or index by position or name."""

    def __getitem__(self, key):
        if isinstance(key, str):
            for spec in self:
                if spec.name == key:
                    return spec
            raise KeyError(f"no parameter {key!r}; parameters are {', '.join(self.names)}")
        return super().__getitem__(key)

    @property
    def names(self) -> tuple[str, ...]:
        """The parameter names in declaration order."""
        return tuple(spec.name for spec in self)


def from_unconstrained(u, lower: float, upper: float, xp=jnp):
    """Map an unconstrained value to the closed interval [lower, upper] (the module doc's transforms).

    Arguments:
        u: unconstrained value(s), any shape.
        lower: lower bound or ``-inf``.
        upper: upper bound or ``inf``.
        xp: the array module: `jax.numpy` (default, traceable) or ``numpy`` (host arithmetic, no dispatch).

    Returns:
        The constrained value(s), same shape as ``u``.
    """
    lo_finite, up_finite = math.isfinite(lower), math.isfinite(upper)
    if lo_finite and up_finite:
        return lower + (upper - lower) * 0.5 * (1.0 + xp.sin(u))
    if lo_finite:
        return lower - 1.0 + xp.sqrt(u * u + 1.0)
    if up_finite:
        return upper + 1.0 - xp.sqrt(u * u + 1.0)
    return u


def transform_slope(u, lower: float, upper: float) -> np.ndarray:
    """dp/du of `from_unconstrained` at ``u``, in closed form (NumPy): (upper − lower)/2 · cos u for two bounds,
    ±u/√(u² + 1) for one, 1 for none. It is 0 on a bound, where the transform turns.

    Arguments:
        u: unconstrained value(s).
        lower, upper: the bounds (``±inf`` for none).

    Returns:
        The slopes, same shape as ``u``.
    """
    u = np.asarray(u, dtype=float)
    lo_finite, up_finite = math.isfinite(lower), math.isfinite(upper)
    if lo_finite and up_finite:
        return 0.5 * (upper - lower) * np.cos(u)
    if lo_finite or up_finite:
        return (1.0 if lo_finite else -1.0) * u / np.sqrt(u * u + 1.0)
    return np.ones_like(u)


def to_unconstrained(value, lower: float, upper: float, xp=jnp):
    """An inverse of `from_unconstrained` (the branch with u >= 0 for a one-sided bound, |u| <= π/2 for two);
    values beyond a bound map to the bound.

    Arguments:
        value: constrained value(s).
        lower: lower bound or ``-inf``.
        upper: upper bound or ``inf``.
        xp: the array module (see `from_unconstrained`).

    Returns:
        The unconstrained value(s).
    """
    value = xp.asarray(value, dtype=float)
    lo_finite, up_finite = math.isfinite(lower), math.isfinite(upper)
    if lo_finite and up_finite:
        return xp.arcsin(xp.clip(2.0 * (value - lower) / (upper - lower) - 1.0, -1.0, 1.0))
    if lo_finite:
        return xp.sqrt(xp.square(xp.maximum(value - lower, 0.0) + 1.0) - 1.0)
    if up_finite:
        return xp.sqrt(xp.square(xp.maximum(upper - value, 0.0) + 1.0) - 1.0)
    return value


def bound_margin(spec: ParamSpec, fraction: float) -> float:
    """A distance from the bounds that counts as "on the bound": ``fraction`` of the bounded range, or of the
    default's magnitude (at least 1e-3) when a bound is infinite.

    Arguments:
        spec: the parameter declaration.
        fraction: the fraction of the parameter's scale.

    Returns:
        The distance, in the parameter's unit.
    """
    if math.isfinite(spec.lower) and math.isfinite(spec.upper):
        return fraction * (spec.upper - spec.lower)
    return fraction * max(abs(spec.default), 1e-3)


def at_bound(value, spec: ParamSpec, fraction: float = 1e-4) -> np.ndarray:
    """True where ``value`` lies within `bound_margin` of one of the spec's finite bounds.

    Fits approach a bound only asymptotically through the transforms, so "at the bound" means "closer than a
    small fraction of the parameter's scale".

    Arguments:
        value: parameter value(s).
        spec: the declaration whose bounds are tested.
        fraction: see `bound_margin`.

    Returns:
        Boolean array of the value's shape.
    """
    value = np.asarray(value, dtype=float)
    margin = bound_margin(spec, fraction)
    hit = np.zeros(value.shape, dtype=bool)
    for bound in (spec.lower, spec.upper):
        if math.isfinite(bound):
            hit |= np.abs(value - bound) <= margin
    return hit
