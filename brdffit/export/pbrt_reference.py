"""pbrt-v4's BxDFs as formulas, and a reader of the ``MakeNamedMaterial`` statements brdffit writes.

No pbrt-v4 package can be installed, so the export is checked against these formulas, transcribed from
pbrt-v4 (github.com/mmp/pbrt-v4, commit 5f7a606): ``src/pbrt/bxdfs.h`` (``DiffuseBxDF::f``,
``ConductorBxDF::f``), ``src/pbrt/util/scattering.h`` (``TrowbridgeReitzDistribution::D``, ``Lambda``, ``G``,
``EffectivelySmooth``; ``FrComplex``) and ``src/pbrt/materials.h`` / ``materials.cpp`` (``DiffuseMaterial``
clamps its reflectance to [0, 1]; ``ConductorMaterial`` takes ``eta``/``k``, ``roughness`` and
``remaproughness``, default true, α = √roughness; ``MixMaterial::ChooseMaterial`` picks ``materials[1]`` with
probability ``amount``, so its expected BSDF is (1 − amount) f0 + amount f1). Evaluated in float64.

``coateddiffuse`` (``CoatedDiffuseMaterial``, ``LayeredBxDF<DielectricBxDF, DiffuseBxDF, true>::f``) is a random
walk whose expectation has no closed form: it is evaluated here as `brdffit.models.coateddiffuse` derives it
(``DielectricBxDF::f`` for the interface's reflection, then the light through the base by that module's
quadrature, in NumPy), for the slab that module covers (thickness 0.01, albedo 0, g 0, maxdepth 10, a rough
interface). tests/test_coateddiffuse.py checks that quadrature against a transcription of pbrt-v4's walk. So is
``coatedconductor`` with a smooth interface (``LayeredBxDF<DielectricBxDF, ConductorBxDF, true>::f``), as
`brdffit.models.coatedconductor` derives it over ``ConductorBxDF::f`` transcribed here (tests/test_coatedconductor.py).
"""

from __future__ import annotations

import re

import numpy as np

from .terms import ExportError

__all__ = ["parse", "evaluate", "fr_complex", "trowbridge_reitz"]

# A quoted string, a comment (# to the end of the line, outside quotes), a bracket or a bare word.
_TOKEN = re.compile(r'"[^"]*"|#[^\n]*|\[|\]|[^\s\[\]"#]+')


def _tokens(text: str) -> list[str]:
    return [t for t in _TOKEN.findall(text) if not t.startswith("#")]


def _value(token: str):
    if token.startswith('"'):
        return token[1:-1]
    if token in ("true", "false"):
        return token == "true"
    try:
        return float(token)
    except ValueError:
        raise ExportError(f"pbrt text: unexpected token {token!r}") from None


def parse(text: str) -> dict:
    """The named materials of a pbrt-v4 scene text.

    Arguments:
        text: scene text with ``MakeNamedMaterial "name" "type key" [ values ] ...`` statements (comments start
            with ``#``).

    Returns:
        name -> {key: value or list of values, "type": the material type}.

    Raises:
        ExportError: a statement other than ``MakeNamedMaterial``, or a malformed parameter list.
    """
    tokens, materials, i = _tokens(text), {}, 0
    while i < len(tokens):
        if tokens[i] != "MakeNamedMaterial":
            raise ExportError(f"pbrt text: expected MakeNamedMaterial, got {tokens[i]!r}")
        name, params, i = _value(tokens[i + 1]), {}, i + 2
        while i < len(tokens) and tokens[i].startswith('"'):
            tag_key = _value(tokens[i]).split()
            if len(tag_key) != 2:
                raise ExportError(f"pbrt text: parameter {tokens[i]} is not \"type name\"")
            if tokens[i + 1] == "[":
                end = tokens.index("]", i + 2)
                values = [_value(t) for t in tokens[i + 2:end]]
                i = end + 1
            else:
                values, i = [_value(tokens[i + 1])], i + 2
            params[tag_key[1]] = values[0] if len(values) == 1 and tag_key[0] != "rgb" else values
        materials[name] = params
    return materials


def fr_complex(cos_theta, eta, k):
    """pbrt-v4 ``FrComplex``: unpolarised Fresnel reflectance of η + ik from vacuum, cosθ clamped to [0, 1]."""
    c = np.clip(cos_theta, 0.0, 1.0)
    n = np.asarray(eta, dtype=complex) + 1j * np.asarray(k, dtype=float)
    sin2_t = (1.0 - c * c) / (n * n)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_parl = (n * c - cos_t) / (n * c + cos_t)
    r_perp = (c - n * cos_t) / (c + n * cos_t)
    return 0.5 * (np.abs(r_parl) ** 2 + np.abs(r_perp) ** 2)


def trowbridge_reitz(alpha: float):
    """pbrt-v4 ``TrowbridgeReitzDistribution`` (isotropic) as (D(cosθm), Λ(cosθ)), with its α >= 1e-4 guard.

    D = 1/(π α² cos⁴θm (1 + tan²θm/α²)²), Λ = (√(1 + α² tan²θ) − 1)/2; G = 1/(1 + Λ(ωo) + Λ(ωi)).
    """
    alpha = max(float(alpha), 1e-4)

    def D(cos_m):
        c2 = cos_m * cos_m
        tan2 = (1.0 - c2) / c2
        return 1.0 / (np.pi * alpha * alpha * c2 * c2 * (1.0 + tan2 / (alpha * alpha)) ** 2)

    def Lambda(cos_v):
        c2 = cos_v * cos_v
        return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2) - 1.0)

    return D, Lambda


def _rgb(value) -> np.ndarray:
    return np.asarray(value, dtype=float).reshape(-1)[:3] * np.ones(3)


def evaluate(materials: dict, name: str, wi, wo) -> np.ndarray:
    """f_r of a named material (without the cosine), as pbrt-v4's ``f(wo, wi)`` computes it.

    Arguments:
        materials: `parse` output.
        name: the material to evaluate.
        wi, wo: ``(n, 3)`` unit vectors above the surface.

    Returns:
        ``(n, 3)`` RGB values in 1/sr (the expected value for ``mix``).

    Raises:
        ExportError: a material type these formulas do not cover.
    """
    mat = materials[name]
    kind = mat.get("type")
    ci, co = wi[:, 2], wo[:, 2]
    above = (ci > 0) & (co > 0)
    if kind == "diffuse":
        rho = np.clip(_rgb(mat.get("reflectance", 0.5)), 0.0, 1.0)
        return np.where(above[:, None], rho / np.pi, 0.0)
    if kind == "mix":
        first, second = mat["materials"]
        amount = float(mat.get("amount", 0.5))
        if amount <= 0.0:
            return evaluate(materials, first, wi, wo)
        if amount >= 1.0:
            return evaluate(materials, second, wi, wo)
        return (1.0 - amount) * evaluate(materials, first, wi, wo) + amount * evaluate(materials, second, wi, wo)
    if kind == "conductor":
        alpha = _alpha(mat)
        if alpha < 1e-3:                                  # EffectivelySmooth: a mirror, f = 0 off the delta
            return np.zeros((len(wi), 3))
        f = _microfacet_reflection(alpha, _rgb(mat["eta"]), _rgb(mat["k"]), wi, wo)
        return np.where(above[:, None], f, 0.0)
    if kind == "coateddiffuse":
        return np.where(above[:, None], _coated_diffuse(mat, name, wi, wo), 0.0)
    if kind == "coatedconductor":
        return np.where(above[:, None], _coated_conductor(mat, name, wi, wo), 0.0)
    raise ExportError(f"pbrt material {name!r} of type {kind!r}: no formula here")


def _coated_diffuse(mat: dict, name: str, wi, wo) -> np.ndarray:
    """f_r of a ``coateddiffuse`` material (module doc), above the surface."""
    from ..models import coateddiffuse as cd

    _slab(mat, name, "coateddiffuse")
    alpha = _alpha(mat)
    eta = float(mat.get("eta", 1.5))
    if alpha < 1e-3 or not cd.MIN_ETA <= eta <= cd.MAX_ETA:
        raise ExportError(f"pbrt material {name!r}: coateddiffuse with alpha {alpha:g} and eta {eta:g}; the formulas "
                          f"here cover a rough interface (alpha >= 1e-3) of eta in [{cd.MIN_ETA:g}, {cd.MAX_ETA:g}]")
    rho = np.clip(_rgb(mat.get("reflectance", 0.5)), 0.0, 1.0)
    reflection = _microfacet_reflection(alpha, eta, 0.0, wi, wo)  # DielectricBxDF::f: FrComplex with k = 0, η > 1
    return reflection + cd.through_the_base(np.maximum(wo[:, 2], 0.0), np.maximum(wi[:, 2], 0.0), rho, alpha, eta, np)


def _slab(mat: dict, name: str, kind: str) -> None:
    """Refuse a layered material whose slab is not the one the formulas here cover (thickness 0.01, maxdepth 10,
    albedo 0, g 0: `brdffit.models.coateddiffuse`'s constants)."""
    from ..models import coateddiffuse as cd

    slab = {"thickness": cd.THICKNESS, "maxdepth": cd.MAX_DEPTH, "g": 0.0, "albedo": [0.0, 0.0, 0.0]}
    for key, covered in slab.items():
        given = mat.get(key, covered)
        if not np.allclose(np.asarray(given, dtype=float), np.asarray(covered, dtype=float), rtol=0.0, atol=0.0):
            raise ExportError(f"pbrt material {name!r}: {kind} with {key} {given}; the formulas here cover "
                              f"{key} {covered} only")


def _coated_conductor(mat: dict, name: str, wi, wo) -> np.ndarray:
    """f_r of a ``coatedconductor`` material with a smooth interface (`brdffit.models.coatedconductor`'s
    expectation of the walk, in NumPy, over ``ConductorBxDF::f`` as transcribed here), above the surface. The metal
    is ``conductor.eta`` and ``conductor.k``, or ``reflectance`` r (newer pbrt-v4: η = 1, k = 2√r/√(1 − r), r
    clamped to [0, 0.9999]), divided by ``interface.eta`` (``CoatedConductorMaterial::GetBxDF``)."""
    from ..geometry import LocalPair
    from ..models import coatedconductor as cc
    from ..models import coateddiffuse as cd

    _slab(mat, name, "coatedconductor")
    interface = _alpha(mat, "interface.roughness")
    alpha = _alpha(mat, "conductor.roughness")
    eta = float(mat.get("interface.eta", 1.5))
    if interface >= 1e-3 or alpha < 1e-3 or not cd.MIN_ETA <= eta <= cd.MAX_ETA:
        raise ExportError(f"pbrt material {name!r}: coatedconductor with interface roughness {interface:g}, "
                          f"conductor roughness {alpha:g} and interface.eta {eta:g}; the formulas here cover a smooth "
                          f"interface (alpha < 1e-3) of eta in [{cd.MIN_ETA:g}, {cd.MAX_ETA:g}] over a rough "
                          "conductor (alpha >= 1e-3)")
    if "reflectance" in mat:
        r = np.clip(_rgb(mat["reflectance"]), 0.0, cc.MAX_REFLECTANCE)
        eta_c, k_c = np.ones(3), 2.0 * np.sqrt(r) / np.sqrt(1.0 - r)
    elif "conductor.eta" in mat and "conductor.k" in mat:
        eta_c, k_c = _rgb(mat["conductor.eta"]), _rgb(mat["conductor.k"])
    else:
        raise ExportError(f"pbrt material {name!r}: coatedconductor without an RGB conductor.eta and conductor.k "
                          "or reflectance (pbrt-v4's default, copper's named spectra, is not covered here)")

    def conductor(pair):
        shape = pair.wi.shape[:-1]
        f = _microfacet_reflection(alpha, eta_c / eta, k_c / eta, pair.wi.reshape(-1, 3), pair.wo.reshape(-1, 3))
        return f.reshape(shape + (3,))

    return cc.beneath(LocalPair.from_dirs(wi, wo, xp=np), eta, conductor, np)


def _alpha(mat: dict, key: str = "roughness") -> float:
    """The Trowbridge-Reitz α of a material's float ``key`` (its square root unless ``remaproughness`` is false:
    ``RoughnessToAlpha``)."""
    roughness = float(mat.get(key, 0.0))
    return np.sqrt(roughness) if mat.get("remaproughness", True) else roughness


def _microfacet_reflection(alpha: float, eta, k, wi, wo) -> np.ndarray:
    """F_complex(|ωo·h|; η + ik) D(h) G(ωo, ωi) / (4 cosθi cosθo) ``(n, C)``, C the channels of η and k:
    ``ConductorBxDF::f``, and with k = 0 the reflection of ``DielectricBxDF::f`` (its FrDielectric for η > 1), for
    ``wi``, ``wo`` above the surface (the cosines floored at 1e-300 elsewhere, where callers mask it)."""
    ci, co = np.maximum(wi[:, 2], 1e-300), np.maximum(wo[:, 2], 1e-300)
    D, Lambda = trowbridge_reitz(alpha)
    wm = wi + wo
    wm = wm / np.linalg.norm(wm, axis=1, keepdims=True)
    F = fr_complex(np.abs(np.sum(wo * wm, axis=1))[:, None], eta, k)
    G = 1.0 / (1.0 + Lambda(co) + Lambda(ci))
    return (D(wm[:, 2]) * G / (4.0 * ci * co))[:, None] * F
