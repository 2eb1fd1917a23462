"""Ward's elliptical Gaussian lobes: isotropic, anisotropic, and Dür's corrected normalisation."""

from __future__ import annotations

import dataclasses

from .._lazy import module
from ..geometry import LocalPair
from .lobe import Lobe
from .peaks import Peak, scalar
from .specs import KS, roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["Ward", "WardAniso", "WardDuer"]


def ward_lobe(pair: LocalPair, ks, alpha_x, alpha_y, duer: bool):
    r"""Ward (1992), Eq. 5: ks exp(−((h·x/αx)² + (h·y/αy)²)/(n·h)²)/(4π αx αy √(cosθi cosθo)).

    With ``duer`` the square root is replaced by cosθi cosθo (Dür, An improved normalization for the Ward
    reflectance model, JGT 11(1), 2006, Eq. 6). (h·x)² + (h·y)² over (n·h)² is tan²θh in the isotropic case.
    """
    hx, hy, ch = pair.h[..., 0], pair.h[..., 1], pair.cos_h
    exponent = ((hx / alpha_x) ** 2 + (hy / alpha_y) ** 2) / (ch * ch)
    cos_product = pair.cos_i * pair.cos_o
    norm = cos_product if duer else jnp.sqrt(cos_product)
    return ks * (jnp.exp(-exponent) / (4.0 * jnp.pi * alpha_x * alpha_y * norm))[..., None]


@dataclasses.dataclass(frozen=True)
class Ward(Lobe):
    """Isotropic Ward: ks exp(−tan²θh/α²)/(4π α² √(cosθi cosθo)). Reciprocal; with ks = 1 its albedo stays
    below 1 up to about 89.8° of incidence and exceeds 1 only beyond (docs/properties.md)."""

    name = "ward"
    reference = "Ward, Measuring and modeling anisotropic reflection, SIGGRAPH 1992, Eq. 5"

    def param_specs(self):
        return (KS, roughness("alpha", doc="RMS slope of the surface"))

    def peaks(self, params):
        return (Peak("half", scalar(params, "alpha")),)

    def __call__(self, params, pair: LocalPair):
        return ward_lobe(pair, params["ks"], params["alpha"], params["alpha"], duer=False)


@dataclasses.dataclass(frozen=True)
class WardAniso(Lobe):
    """Anisotropic Ward with widths αx along the tangent and αy along the bitangent."""

    name = "ward-aniso"
    reference = "Ward, Measuring and modeling anisotropic reflection, SIGGRAPH 1992, Eq. 5"

    def param_specs(self):
        return (
            KS,
            roughness("alpha_x", doc="RMS slope along the tangent x"),
            roughness("alpha_y", doc="RMS slope along the bitangent y"),
        )

    def peaks(self, params):
        return (Peak("half", scalar(params, "alpha_x")), Peak("half", scalar(params, "alpha_y")))

    def __call__(self, params, pair: LocalPair):
        return ward_lobe(pair, params["ks"], params["alpha_x"], params["alpha_y"], duer=False)


@dataclasses.dataclass(frozen=True)
class WardDuer(Lobe):
    """Isotropic Ward with Dür's normalisation 1/(4π α² cosθi cosθo). Closer to energy balance than Ward's
    √(cosθi cosθo) away from grazing for small α, but its albedo grows without bound towards grazing incidence
    (9.9 at 89.5° for α = 0.5, ks = 1; docs/properties.md)."""

    name = "ward-duer"
    reference = "Dür, An improved normalization for the Ward reflectance model, JGT 11(1), 2006"

    def param_specs(self):
        return (KS, roughness("alpha", doc="RMS slope of the surface"))

    def peaks(self, params):
        return (Peak("half", scalar(params, "alpha")),)

    def __call__(self, params, pair: LocalPair):
        return ward_lobe(pair, params["ks"], params["alpha"], params["alpha"], duer=True)
