"""Export a fitted model as JSON, as a Mitsuba 3 ``<bsdf>`` or as a pbrt-v4 ``MakeNamedMaterial`` statement.

The mapping from brdffit's lobes to the renderers' plugins, and every approximation it makes, is in
docs/export.md. In short:

- ``lambert`` -> Mitsuba ``diffuse`` / pbrt ``diffuse`` (exact: both are ρ/π).
- ``cook-torrance`` / ``ggx`` with ``fresnel=conductor`` -> Mitsuba ``roughconductor`` / pbrt ``conductor``.
- ``lambert`` + ``cook-torrance`` / ``ggx`` with ``fresnel=schlick`` or ``dielectric`` (or the specular lobe
  alone) -> Mitsuba ``roughplastic`` / pbrt ``coateddiffuse``.

Everything else (Oren-Nayar, Phong, Blinn-Phong, Ward, Ashikhmin-Shirley, Lafortune, toon, a conductor lobe
summed with a diffuse one, two specular lobes) has no faithful plugin in either renderer and raises `ExportError`.
A renderer output starts with a comment naming the source spec and the brdffit version, followed by one comment
line per approximation made; the JSON output carries the same text under ``"comment"`` and ``"approximations"``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from xml.sax.saxutils import quoteattr

import numpy as np

__all__ = ["EXPORT_FORMATS", "ExportError", "export", "f0_to_eta"]

EXPORT_FORMATS = ("json", "mitsuba", "pbrt")

_SPECULAR_LOBES = ("cook-torrance", "ggx")
_EXPORTABLE = ("lambert (any number, summed); cook-torrance or ggx with fresnel=conductor alone; "
               "cook-torrance or ggx with fresnel=schlick or dielectric, alone or plus lambert")
# Below this index the dielectric interface reflects (next to) nothing and Mitsuba refuses int_ior == ext_ior.
_MIN_ETA = 1.0 + 1e-6


class ExportError(ValueError):
    """The model has no faithful equivalent in the requested format (the message names the lobe)."""


def f0_to_eta(f0: float) -> float:
    """Refractive index η of the dielectric (seen from vacuum) whose normal-incidence reflectance is f0.

    Inverts f0 = ((η − 1)/(η + 1))²: η = (1 + √f0)/(1 − √f0); f0 = 0.04 gives η = 1.5.

    Raises:
        ExportError: for f0 outside [0, 1).
    """
    f0 = float(f0)
    if not 0.0 <= f0 < 1.0:
        raise ExportError(f"Schlick f0 must lie in [0, 1) to have a dielectric index, got {f0}")
    s = math.sqrt(f0)
    return (1.0 + s) / (1.0 - s)


@dataclasses.dataclass
class _Material:
    """What the renderers need, read off a model: a diffuse albedo and at most one microfacet lobe."""

    spec: str
    channels: int
    rho_d: np.ndarray | None = None
    kind: str | None = None          # None (diffuse only), "conductor" or "dielectric"
    lobe: object = None
    ks: np.ndarray | None = None
    alpha: float | None = None
    eta: float | np.ndarray | None = None
    k: np.ndarray | None = None
    notes: list = dataclasses.field(default_factory=list)


def _unwrap(model_or_result):
    """(model or None, FitResult or None) from a Model, FitResult or spec string."""
    from .fitting.result import FitResult
    from .models import Model, get

    if isinstance(model_or_result, FitResult):
        return model_or_result.model, model_or_result
    if isinstance(model_or_result, Model):
        return model_or_result, None
    if isinstance(model_or_result, str):
        return get(model_or_result), None
    raise TypeError(f"export needs a brdffit Model, FitResult or spec string, got {type(model_or_result).__name__}")


def _values(x) -> np.ndarray:
    return np.atleast_1d(np.asarray(x, dtype=float))


def _analyse(model) -> _Material:
    """Map the model's lobes onto the renderer vocabulary; raise ExportError for lobes without a faithful plugin."""
    mat = _Material(spec=model.spec, channels=model.channels)
    specular = []
    for lobe, names in zip(model.lobes, model.names_by_lobe):
        params = {spec.name: model.params[name] for spec, name in zip(lobe.param_specs(), names)}
        if lobe.name == "lambert":
            rho = _values(params["rho_d"])
            mat.rho_d = rho if mat.rho_d is None else mat.rho_d + rho
        elif lobe.name in _SPECULAR_LOBES:
            specular.append((lobe, params))
        else:
            raise ExportError(f"lobe {lobe.name!r} of model {model.spec!r} has no faithful equivalent in Mitsuba 3 "
                              f"or pbrt-v4; exportable: {_EXPORTABLE} (docs/export.md)")
    if len(specular) > 1:
        raise ExportError(f"model {model.spec!r} has {len(specular)} microfacet lobes ({specular[1][0].name!r} "
                          f"is the second); the renderers' plugins hold one; exportable: {_EXPORTABLE}")
    if not specular:
        return mat
    lobe, params = specular[0]
    mat.lobe = lobe
    mat.ks = _values(params["ks"])
    mat.alpha = float(params[lobe.roughness_name])
    if lobe.fresnel == "conductor":
        if mat.rho_d is not None:
            raise ExportError(f"lobe {lobe.name!r} with fresnel=conductor summed with a lambert lobe (model "
                              f"{model.spec!r}) has no single plugin in Mitsuba 3 or pbrt-v4; exportable: "
                              f"{_EXPORTABLE}")
        mat.kind = "conductor"
        mat.eta, mat.k = _values(params["eta"]), _values(params["k"])
    else:
        mat.kind = "dielectric"
        if lobe.fresnel == "schlick":
            f0 = float(params["f0"])
            mat.eta = f0_to_eta(f0)
            mat.notes.append(f"Schlick f0 = {_num(f0)} became the exact dielectric Fresnel of eta = "
                             f"(1 + sqrt(f0))/(1 - sqrt(f0)) = {_num(mat.eta)}; equal at normal incidence, "
                             "Schlick differs by up to a few percent towards grazing")
        else:
            mat.eta = float(params["eta"])
        if mat.eta < _MIN_ETA:
            mat.notes.append(f"the {lobe.name} lobe has eta = {_num(mat.eta)} (f0 = 0): it reflects nothing and "
                             "was dropped")
            mat.kind, mat.lobe, mat.ks, mat.alpha, mat.eta = None, None, None, None, None
            if mat.rho_d is None:
                mat.rho_d = np.zeros(model.channels)
            return mat
    if lobe.shadowing == "v-cavity":
        mat.notes.append("Cook-Torrance V-cavity shadowing became the renderer's Smith shadowing-masking")
    elif lobe.shadowing == "none":
        mat.notes.append("shadowing=none became the renderer's Smith shadowing-masking")
    return mat


def _num(v) -> str:
    return format(float(v), ".10g")


def _check_channels(mat: _Material, to: str):
    if mat.channels not in (1, 3):
        raise ExportError(f"{to} takes RGB colours; model {mat.spec!r} has {mat.channels} channels (spectral data "
                          "need the wavelengths, which a model does not carry); fit RGB or single-channel data")


def _rgb(values) -> list[float]:
    values = _values(values)
    return [float(values[0])] * 3 if values.size == 1 else [float(v) for v in values]


def _version() -> str:
    import brdffit

    return getattr(brdffit, "__version__", "unknown")


def _header(mat: _Material, to: str) -> list[str]:
    lines = [f"brdffit {_version()} export of model {mat.spec} to {to}"]
    lines.extend(f"approximation: {note}" for note in mat.notes)
    return lines


# ---------------------------------------------------------------------------------------------------------- Mitsuba


def _mitsuba(mat: _Material, name: str) -> str:
    _check_channels(mat, "Mitsuba 3")
    lobe = mat.lobe
    if mat.kind is not None:
        distribution = "ggx" if lobe.distribution == "ggx" else "beckmann"
    if mat.kind is None:
        plugin = "diffuse"
        body = [("rgb", "reflectance", mat.rho_d)]
    elif mat.kind == "conductor":
        plugin = "roughconductor"
        body = [("string", "distribution", distribution), ("float", "alpha", mat.alpha), ("rgb", "eta", mat.eta),
                ("rgb", "k", mat.k), ("rgb", "specular_reflectance", mat.ks)]
    else:
        plugin = "roughplastic"
        rho = mat.rho_d if mat.rho_d is not None else np.zeros(mat.channels)
        body = [("string", "distribution", distribution), ("float", "alpha", mat.alpha),
                ("float", "int_ior", mat.eta), ("float", "ext_ior", 1.0), ("rgb", "diffuse_reflectance", rho),
                ("rgb", "specular_reflectance", mat.ks)]
        if mat.rho_d is not None:
            mat.notes.append("roughplastic's diffuse term is rho_d/pi times the rough interface's transmittance "
                             "t(theta_i) t(theta_o) / (eta^2 (1 - internal reflectance)), not brdffit's plain "
                             "rho_d/pi: darker towards grazing")
    if mat.kind is not None and lobe.distribution == "blinn":
        mat.notes.append(f"Mitsuba has no Blinn distribution (alpha_p = 2/m^2 - 2): it became Beckmann with the "
                         f"same m = {_num(mat.alpha)}; the two agree closely for small m")
    if mat.kind is not None and not np.allclose(mat.ks, 1.0):
        mat.notes.append("brdffit's specular scale ks went into specular_reflectance, which Mitsuba documents as "
                         "a non-physical modulation (default 1)")
    lines = [f"<!-- {_xml_comment(line)} -->" for line in _header(mat, "Mitsuba 3")]
    lines.append(f"<bsdf type={quoteattr(plugin)} id={quoteattr(name)}>")
    for tag, key, value in body:
        if tag == "rgb":
            text = ", ".join(_num(v) for v in _rgb(value))
        elif tag == "float":
            text = _num(value)
        else:
            text = str(value)
        lines.append(f"    <{tag} name={quoteattr(key)} value={quoteattr(text)}/>")
    lines.append("</bsdf>")
    return "\n".join(lines) + "\n"


def _xml_comment(text: str) -> str:
    while "--" in text:
        text = text.replace("--", "- -")
    return text.rstrip("-")


# ------------------------------------------------------------------------------------------------------------- pbrt


def _pbrt(mat: _Material, name: str) -> str:
    _check_channels(mat, "pbrt-v4")
    if '"' in name or "\n" in name:
        raise ExportError(f"a pbrt material name cannot hold quotes or newlines: {name!r}")
    lobe = mat.lobe
    if mat.kind is not None:
        if lobe.distribution != "ggx":
            mat.notes.append(f"pbrt-v4 has only the Trowbridge-Reitz (GGX) distribution: the {lobe.distribution} "
                             f"width m = {_num(mat.alpha)} was used as the GGX alpha, which has longer tails")
        if lobe.shadowing == "smith":
            mat.notes.append("brdffit's separable Smith G1(wi) G1(wo) became pbrt-v4's height-correlated "
                             "1/(1 + Lambda(wi) + Lambda(wo)), slightly brighter at grazing")
        if not np.allclose(mat.ks, 1.0):
            mat.notes.append(f"pbrt-v4 has no specular scale: ks = {', '.join(_num(v) for v in _rgb(mat.ks))} "
                             "was dropped (ks = 1 assumed)")
    if mat.kind is None:
        body = [("rgb", "reflectance", mat.rho_d)]
        plugin = "diffuse"
    elif mat.kind == "conductor":
        plugin = "conductor"
        body = [("rgb", "eta", mat.eta), ("rgb", "k", mat.k), ("float", "roughness", mat.alpha),
                ("bool", "remaproughness", False)]
    else:
        plugin = "coateddiffuse"
        rho = mat.rho_d if mat.rho_d is not None else np.zeros(mat.channels)
        body = [("rgb", "reflectance", rho), ("float", "roughness", mat.alpha), ("float", "eta", mat.eta),
                ("bool", "remaproughness", False)]
        mat.notes.append("coateddiffuse is a layered BSDF (rough dielectric over a diffuse base, simulated by a "
                         "random walk): its diffuse part is dimmed and tinted by the coating, unlike brdffit's "
                         "plain sum of rho_d/pi and the specular lobe")
    lines = [f"# {line}" for line in _header(mat, "pbrt-v4")]
    lines.append(f'MakeNamedMaterial "{name}"')
    lines.append(f'    "string type" [ "{plugin}" ]')
    for tag, key, value in body:
        if tag == "rgb":
            text = " ".join(_num(v) for v in _rgb(value))
        elif tag == "float":
            text = _num(value)
        else:
            text = "true" if value else "false"
        lines.append(f'    "{tag} {key}" [ {text} ]')
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------------------- JSON


def _json_value(value):
    value = np.asarray(value, dtype=float)
    if value.ndim == 0:
        return float(value) if math.isfinite(float(value)) else None
    return [float(v) if math.isfinite(v) else None for v in value.tolist()]


def _json(model, result) -> str:
    from .models import model_to_dict

    if model is None:
        models = [model_to_dict(m) for m in result.models]
        out = {"comment": f"brdffit {_version()} export of model {result.spec} (one model per channel)",
               "generator": f"brdffit {_version()}", "channel_mode": result.channel_mode, "models": models}
    else:
        out = {"comment": f"brdffit {_version()} export of model {model.spec}", "generator": f"brdffit {_version()}"}
        out.update(model_to_dict(model))
    if result is not None:
        out["stderr"] = {k: _json_value(v) for k, v in result.stderr.items()}
        out["status"] = result.status
    return json.dumps(out, indent=2) + "\n"


# --------------------------------------------------------------------------------------------------------------- API


def export(model_or_result, to: str = "json", *, name: str = "material") -> str:
    """Write a model (or the model of a fit) in a renderer's own terms.

    Arguments:
        model_or_result: a `brdffit.Model`, a `brdffit.FitResult` or a spec string (default parameters).
        to: ``"json"`` (brdffit's own description: spec, channels, parameters, plus ``stderr`` and ``status``
            for a `FitResult`; `brdffit.models.model_from_dict` reads it back), ``"mitsuba"`` (a Mitsuba 3
            ``<bsdf>`` element) or ``"pbrt"`` (a pbrt-v4 ``MakeNamedMaterial`` statement).
        name: the material's id (Mitsuba) or name (pbrt).

    Returns:
        The text. Renderer outputs open with comments naming the source spec, the brdffit version and each
        approximation the mapping made (docs/export.md).

    Raises:
        ExportError: the model has a lobe (or combination of lobes) with no faithful equivalent in that renderer,
            or more channels than RGB. ValueError: unknown format.
    """
    if to not in EXPORT_FORMATS:
        raise ValueError(f"unknown export format {to!r}; choose one of {', '.join(EXPORT_FORMATS)}")
    model, result = _unwrap(model_or_result)
    if to == "json":
        return _json(model, result)
    if model is None:
        raise ExportError(f"a fit in channel_mode='independent' has one model per channel ({result.spec}); "
                          f"{to} needs one material: refit with channel_mode='shared-shape' or export to json")
    mat = _analyse(model)
    return _mitsuba(mat, name) if to == "mitsuba" else _pbrt(mat, name)
