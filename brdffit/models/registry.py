"""The registry of lobes and the parser of model spec strings.

A spec is a lobe name or a sum of lobes joined with ``+``; a lobe may carry its own options in brackets:
``"lambert+cook-torrance(distribution=ggx, fresnel=conductor, material=gold)"``.
"""

from __future__ import annotations

import dataclasses
import re

from .._lazy import module
from .abc import ABCMicrofacet, ABCSmooth
from .ashikhmin_shirley import AshikhminShirley, AshikhminShirleyAniso
from .coatedconductor import CoatedConductor
from .coateddiffuse import CoatedDiffuse
from .cook_torrance import GGX, CookTorrance
from .blender import BlenderPrincipled
from .diffuse import Burley, Lambert, OrenNayar
from .gltf import GltfMaterial
from .lafortune import Lafortune
from .lobe import Lobe
from .openpbr import OpenPBR
from .layout import layout
from .pbrt import PbrtMaterial
from .phong import BlinnPhong, Phong
from .principled import Principled
from .roughplastic import RoughPlastic
from .sgd import SGD
from .sheen import CharlieSheen, Sheen
from .toon import ToonDiffuse, ToonSpecular
from .ward import Ward, WardAniso, WardDuer

# The composed Model (JAX) is loaded when a model is built, not when the registry is read.
_model = module("brdffit.models.model")
_arrays = module("brdffit.arrays")  # NumPy, loaded with the model: reading the registry loads neither

__all__ = ["names", "get", "lobe_class", "parse_spec", "describe", "model_to_dict", "model_from_dict"]

_LOBES: dict[str, type[Lobe]] = {
    cls.name: cls
    for cls in (
        Lambert,
        OrenNayar,
        Burley,
        Phong,
        BlinnPhong,
        Ward,
        WardAniso,
        WardDuer,
        CookTorrance,
        GGX,
        AshikhminShirley,
        AshikhminShirleyAniso,
        Lafortune,
        ABCSmooth,
        ABCMicrofacet,
        SGD,
        Sheen,
        CharlieSheen,
        Principled,
        GltfMaterial,
        BlenderPrincipled,
        OpenPBR,
        PbrtMaterial,
        CoatedDiffuse,
        CoatedConductor,
        RoughPlastic,
        ToonDiffuse,
        ToonSpecular,
    )
}

_TOKEN = re.compile(r"^\s*([a-z0-9-]+)\s*(?:\((.*)\))?\s*$")


def names() -> list[str]:
    """The registered lobe names, in registry order."""
    return list(_LOBES)


def lobe_class(name: str) -> type[Lobe]:
    """The lobe class registered under ``name``; a KeyError lists the valid names."""
    try:
        return _LOBES[name]
    except KeyError:
        raise KeyError(f"unknown lobe {name!r}; known lobes: {', '.join(_LOBES)}") from None


def _parse_option_value(text: str):
    text = text.strip()
    for convert in (int, float):
        try:
            return convert(text)
        except ValueError:
            pass
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    return text


def parse_spec(spec: str) -> list[tuple[str, dict]]:
    """Split a spec string into ``(lobe name, bracketed options)`` pairs.

    Arguments:
        spec: e.g. ``"lambert+ward"`` or ``"lambert+lafortune(lobes=2)"``.

    Returns:
        One ``(name, options)`` pair per lobe.

    Raises:
        ValueError: if the spec is empty or a lobe token is malformed.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"a model spec must be a non-empty string such as 'lambert+ward', got {spec!r}")
    tokens = []
    depth, start = 0, 0
    for pos, char in enumerate(spec + "+"):
        depth += (char == "(") - (char == ")")
        if char == "+" and depth == 0:
            tokens.append(spec[start:pos])
            start = pos + 1
    parsed = []
    for token in tokens:
        match = _TOKEN.match(token.lower())
        if not match:
            raise ValueError(f"cannot read lobe {token!r} in model spec {spec!r}; write e.g. 'lambert+ggx' or "
                             "'cook-torrance(distribution=ggx)'")
        options = {}
        if match.group(2):
            for item in match.group(2).split(","):
                if "=" not in item:
                    raise ValueError(f"lobe option {item.strip()!r} in {spec!r} needs the form key=value")
                key, value = item.split("=", 1)
                options[key.strip().replace("-", "_")] = _parse_option_value(value)
        parsed.append((match.group(1), options))
    return parsed


def get(spec, channels: int = 3, **options_and_params) -> "Model":
    """Build a model from a spec string.

    Arguments:
        spec: a lobe name or a sum joined with ``+`` (e.g. ``"lambert+cook-torrance"``), or an existing `Model`
            (its lobes are kept and the keywords replace parameter values).
        channels: number of channels (3 for RGB, the number of wavelengths for spectral data).
        **options_and_params: lobe options (``distribution="ggx"``, ``lobes=2``, ...) apply to every lobe of the
            sum that accepts them; any other keyword is a parameter value under its model-level name. Parameters
            not given take their declared defaults.

    Returns:
        The `Model`.

    Raises:
        KeyError: unknown lobe name. ValueError: malformed spec, unknown keyword, wrong value shape, or an
        invalid option value.
    """
    if isinstance(spec, _model.Model):
        return spec.replace(**options_and_params)
    if not isinstance(channels, int) or channels < 1:
        raise ValueError(f"channels must be a positive integer, got {channels!r}")
    parsed = parse_spec(spec)
    classes = [lobe_class(name) for name, _ in parsed]
    shared_options = {k: v for k, v in options_and_params.items()
                      if any(k in cls.option_names() for cls in classes)}
    lobes = []
    for cls, (name, own) in zip(classes, parsed):
        unknown = set(own) - set(cls.option_names())
        if unknown:
            raise ValueError(f"lobe {name!r} has no option {sorted(unknown)[0]!r}; its options are "
                             f"{', '.join(cls.option_names()) or 'none'}")
        kwargs = {k: v for k, v in shared_options.items() if k in cls.option_names()}
        kwargs.update(own)
        lobes.append(cls(**kwargs))
    lobes = tuple(lobes)
    specs = layout(lobes, channels).specs
    values = {k: v for k, v in options_and_params.items() if k not in shared_options}
    known = {s.name for s in specs}
    unknown = set(values) - known
    if unknown:
        raise ValueError(f"model {spec!r} has no parameter or option {sorted(unknown)[0]!r}; parameters: "
                         f"{', '.join(s.name for s in specs)}")
    params = _arrays.on_device({s.name: _model.coerce_value(s, values[s.name], channels) if s.name in values
                               else s.initial(channels) for s in specs})
    return _model.Model(params=params, lobes=lobes, channels=channels)


def describe(spec_class: type[Lobe]) -> str:
    """One paragraph on a lobe class: name, reference and its own options (used by ``brdffit models``; the
    options every lobe has, `COMMON_OPTIONS`, are described once, in docs/models.md)."""
    from .lobe import COMMON_OPTIONS

    own = [f for f in dataclasses.fields(spec_class) if f.name not in COMMON_OPTIONS]
    opts = ", ".join(f"{f.name}={f.default!r}" for f in own) or "none"
    return f"{spec_class.name}: {spec_class.reference} (options: {opts})"


def model_to_dict(model: "Model") -> dict:
    """A JSON-ready description of a model: its spec (with lobe options), channel count and parameter values.

    Arguments:
        model: the `Model`.

    Returns:
        ``{"spec": str, "channels": int, "params": {name: float or list of floats}}``; `model_from_dict` inverts it.
    """
    import numpy as np

    params = {name: np.asarray(value).tolist() for name, value in model.params.items()}
    return {"spec": model.spec, "channels": model.channels, "params": params}


def model_from_dict(description: dict) -> "Model":
    """Rebuild a model from `model_to_dict`'s output.

    Arguments:
        description: a dict with ``spec``, ``channels`` and ``params``.

    Returns:
        The `Model`.
    """
    return get(description["spec"], channels=int(description["channels"]), **description["params"])
