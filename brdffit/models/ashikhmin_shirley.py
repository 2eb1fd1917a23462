"""Ashikhmin-Shirley anisotropic Phong specular lobe (isotropic and anisotropic)."""

from __future__ import annotations

import dataclasses

from .._lazy import module
from ..geometry import LocalPair, safe_div
from ..params import ParamSpec
from .fresnel import schlick
from .lobe import Lobe
from .peaks import Peak, power_width, scalar
from .specs import exponent

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["AshikhminShirley", "AshikhminShirleyAniso"]

RS = ParamSpec("rs", 0.05, 0.0, 1.0, colour=True, unit="1", doc="specular reflectance at normal incidence",
               linear=True)


def ashikhmin_shirley_lobe(pair: LocalPair, rs, nu, nv):
    r"""Ashikhmin & Shirley (2000), Eq. 4: √((nu+1)(nv+1))/(8π) (n·h)^e / ((ωi·h) max(cosθi, cosθo)) F(ωi·h),
    e = (nu (h·x)² + nv (h·y)²)/(1 − (n·h)²), F Schlick's with normal reflectance rs.

    1 − (n·h)² equals (h·x)² + (h·y)², so e is a weighted mean of nu and nv; at h = n it is taken as (nu + nv)/2,
    its value for the isotropic case.
    """
    hx2, hy2 = pair.h[..., 0] ** 2, pair.h[..., 1] ** 2
    e = safe_div(nu * hx2 + nv * hy2, hx2 + hy2, fallback=0.5 * (nu + nv))
    lobe = (jnp.sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * jnp.pi) * jnp.exp(e * jnp.log(pair.cos_h))
            / (pair.cos_d * jnp.maximum(pair.cos_i, pair.cos_o)))
    return lobe[..., None] * schlick(pair.cos_d[..., None], rs)


@dataclasses.dataclass(frozen=True)
class AshikhminShirley(Lobe):
    """Isotropic Ashikhmin-Shirley specular lobe (nu = nv = n)."""

    name = "ashikhmin-shirley"
    reference = "Ashikhmin & Shirley, An anisotropic Phong BRDF model, JGT 5(2), 2000, Eq. 4"
    offset = True  # its Fresnel term rs + (1 - rs)(1 - h·k)^5 is affine in rs

    def param_specs(self):
        return (RS, exponent("n", 100.0, doc="Phong-like exponent"))

    def peaks(self, params):
        return (Peak("half", power_width(scalar(params, "n"))),)

    def __call__(self, params, pair: LocalPair):
        return ashikhmin_shirley_lobe(pair, params["rs"], params["n"], params["n"])


@dataclasses.dataclass(frozen=True)
class AshikhminShirleyAniso(Lobe):
    """Anisotropic Ashikhmin-Shirley specular lobe with exponents nu (along x) and nv (along y)."""

    name = "ashikhmin-shirley-aniso"
    reference = "Ashikhmin & Shirley, An anisotropic Phong BRDF model, JGT 5(2), 2000, Eq. 4"
    offset = True  # its Fresnel term rs + (1 - rs)(1 - h·k)^5 is affine in rs

    def param_specs(self):
        return (RS, exponent("nu", 100.0, doc="exponent along the tangent x"),
                exponent("nv", 100.0, doc="exponent along the bitangent y"))

    def peaks(self, params):
        return (Peak("half", power_width(scalar(params, "nu"))), Peak("half", power_width(scalar(params, "nv"))))

    def __call__(self, params, pair: LocalPair):
        return ashikhmin_shirley_lobe(pair, params["rs"], params["nu"], params["nv"])
