"""The Cook-Torrance microfacet lobe (with Walter et al.'s normalisation) and its GGX specialisation."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from ..geometry import LocalPair
from ..params import ParamSpec
from . import fresnel as fr
from .lobe import Lobe
from .microfacet import ANISOTROPIC, DISTRIBUTIONS, SHADOWING
from .peaks import Peak, scalar
from .specs import KS, roughness

__all__ = ["CookTorrance", "GGX", "FRESNEL_MODES"]

FRESNEL_MODES = ("schlick", "dielectric", "conductor")
_DEFAULT_CONDUCTOR = "gold"
_DEFAULT_DIELECTRIC = "glass"


@dataclasses.dataclass(frozen=True)
class CookTorrance(Lobe):
    r"""Cook & Torrance (1982) with Walter et al. (2007, Eq. 20) normalisation:
    f = ks F(ωo·h) D(h) G(ωi, ωo) / (4 cosθi cosθo).

    Options:
        distribution: ``"beckmann"`` (default), ``"ggx"``, ``"blinn"``, ``"std"`` (Student-t) or ``"gtr"``
            (Burley's generalised Trowbridge-Reitz), the last two with their exponent ``gamma`` as a parameter
            (`brdffit.models.microfacet`).
        shadowing: ``"v-cavity"`` (default, Cook-Torrance 1982), ``"smith"`` (separable, for the chosen D),
            ``"smith-correlated"`` (height-correlated, Heitz 2014 Eq. 99, as pbrt-v4 renders) or ``"none"``.
        anisotropic: widths ``<r>_x`` along the tangent and ``<r>_y`` along the bitangent instead of one ``<r>``
            (``m`` or ``alpha``), for the Beckmann and GGX distributions (Heitz 2014, §5.3); an isotropic lobe
            keeps αx = αy by declaring one width.
        fresnel: ``"schlick"`` (parameter ``f0``), ``"dielectric"`` (``eta``) or ``"conductor"`` (``eta``, ``k``
            per channel).
        material: a named preset (`brdffit.models.fresnel.CONDUCTORS` or ``DIELECTRICS``) that sets the default
            ``eta`` (and ``k``) of the dielectric or conductor Fresnel term.
    """

    name = "cook-torrance"
    reference = ("Cook & Torrance, A reflectance model for computer graphics, ACM TOG 1982; Walter et al., "
                 "Microfacet models for refraction through rough surfaces, EGSR 2007")
    roughness_name: ClassVar[str] = "m"

    distribution: str = "beckmann"
    shadowing: str = "v-cavity"
    fresnel: str = "schlick"
    material: str | None = None
    anisotropic: bool = False

    def __post_init__(self):
        for option, allowed in (("distribution", DISTRIBUTIONS), ("shadowing", SHADOWING),
                                ("fresnel", FRESNEL_MODES)):
            if getattr(self, option) not in allowed:
                raise ValueError(f"{self.name}: {option} must be one of {', '.join(allowed)}, "
                                 f"got {getattr(self, option)!r}")
        if self.anisotropic and self.distribution not in ANISOTROPIC:
            raise ValueError(f"{self.name}: anisotropic=true needs distribution={' or '.join(ANISOTROPIC)}, got "
                             f"{self.distribution!r}")
        presets = {"conductor": fr.CONDUCTORS, "dielectric": fr.DIELECTRICS}.get(self.fresnel, {})
        if self.material is not None and self.material not in presets:
            raise ValueError(f"{self.name}: material {self.material!r} needs fresnel='conductor' (one of "
                             f"{', '.join(fr.CONDUCTORS)}) or fresnel='dielectric' (one of "
                             f"{', '.join(fr.DIELECTRICS)})")

    @property
    def roughness_names(self) -> tuple[str, ...]:
        """The width parameters: ``(r,)``, or ``(r_x, r_y)`` for an anisotropic lobe."""
        r = self.roughness_name
        return (f"{r}_x", f"{r}_y") if self.anisotropic else (r,)

    def param_specs(self):
        docs = {1: ("microfacet roughness (RMS slope width)",),
                2: ("microfacet roughness along the tangent x", "microfacet roughness along the bitangent y")}
        names = self.roughness_names
        specs = [KS, *(roughness(name, doc=doc) for name, doc in zip(names, docs[len(names)]))]
        tail = DISTRIBUTIONS[self.distribution].tail
        if tail is not None:
            specs.append(tail)
        if self.fresnel == "schlick":
            specs.append(ParamSpec("f0", 0.04, 0.0, 1.0, unit="1", doc="Fresnel reflectance at normal incidence"))
        elif self.fresnel == "dielectric":
            eta = fr.DIELECTRICS[self.material or _DEFAULT_DIELECTRIC]
            specs.append(ParamSpec("eta", eta, 1.0, 4.0, unit="1", doc="refractive index of the dielectric"))
        else:
            eta, k = fr.CONDUCTORS[self.material or _DEFAULT_CONDUCTOR]
            specs.append(ParamSpec("eta", eta, 0.0, 10.0, colour=True, unit="1",
                                   doc="real part of the conductor's refractive index"))
            specs.append(ParamSpec("k", k, 0.0, 20.0, colour=True, unit="1",
                                   doc="extinction coefficient of the conductor"))
        return tuple(specs)

    def fresnel_term(self, params, cos_d):
        """F(ωo·h) for the configured Fresnel mode, shape ``cos_d.shape + (C,)`` or broadcastable to it."""
        c = cos_d[..., None]
        if self.fresnel == "schlick":
            return fr.schlick(c, params["f0"])
        if self.fresnel == "dielectric":
            return fr.dielectric(c, 1.0, params["eta"])
        return fr.conductor(c, params["eta"], params["k"])

    def peaks(self, params):
        """One half-vector peak per width (two for an anisotropic lobe)."""
        return tuple(Peak("half", scalar(params, name)) for name in self.roughness_names)

    def __call__(self, params, pair: LocalPair):
        widths = tuple(params[name] for name in self.roughness_names)
        m = widths if self.anisotropic else widths[0]
        dist = DISTRIBUTIONS[self.distribution]
        tail = params[dist.tail.name] if dist.tail is not None else None
        d = dist.density_of(pair, m, tail)
        g = SHADOWING[self.shadowing](pair, dist, m, tail)
        geometric = d * g / (4.0 * pair.cos_i * pair.cos_o)
        return params["ks"] * self.fresnel_term(params, pair.cos_d) * geometric[..., None]


@dataclasses.dataclass(frozen=True)
class GGX(CookTorrance):
    """Cook-Torrance with the GGX distribution and separable Smith shadowing; roughness named ``alpha``."""

    name = "ggx"
    roughness_name: ClassVar[str] = "alpha"

    distribution: str = "ggx"
    shadowing: str = "smith"
