"""Export a fitted model: brdffit's JSON, a Mitsuba 3 ``<bsdf>`` document, pbrt-v4 ``MakeNamedMaterial``
statements, a glTF 2.0 file, a Blender (bpy) script or a MaterialX document.

One file per target, each with a ``write`` function; `TARGETS` is the registry that the CLI's ``--to`` choices
and `EXPORT_FORMATS` come from. Shared pieces (the lobes as renderer terms, the measured deviation, the Schlick
-> index fit) are in `brdffit.export.terms`; the ``fit`` option is `brdffit.export.refit`, and what it wrote for a
result in a `brdffit fit` output folder is recorded beside it by `brdffit.export.records`. Every renderer output
opens with comments (in a glTF file, ``asset.extras.brdffit``) naming the source spec and the brdffit version, one
``approximation:`` line per approximation made, and the deviation of the written material from the source measured
at 2,000 uniform random direction pairs and pairs near each lobe's peak, combined by the balance heuristic
(`brdffit.export.terms.stated`, `brdffit.export.terms.measure`, docs/export.md).
"""

from __future__ import annotations

import dataclasses

from .registry import APPROXIMATE_GAIN, EXPORT_FORMATS, FIT_TARGETS, TARGETS, ExportError, Target

__all__ = ["EXPORT_FORMATS", "FIT_TARGETS", "TARGETS", "Target", "Export", "ExportError", "export", "export_details",
           "f0_to_eta"]


def __getattr__(name):
    # f0_to_eta lives with the maths (brdffit.export.terms, which loads JAX); the registry above stays light.
    if name == "f0_to_eta":
        from .terms import f0_to_eta

        return f0_to_eta
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclasses.dataclass(frozen=True)
class Export:
    """A renderer export with what it measured.

    Attributes:
        text: the output.
        written: the written material as a function (wi, wo) -> f_r, ``(n, 3)`` (or ``(n, channels)``), by the
            renderer's formulas (Mitsuba's parts in brdffit terms with its Beckmann G1; pbrt-v4's BxDFs).
        source: the model that was exported (the fit's model; before the ``fit`` option).
        notes: the approximations made.
        deviation: `brdffit.export.terms.Deviation` of ``written`` from ``source``.
        mapped: the model whose mapping was written: ``source``, or under the ``fit`` option the brdffit fit of the
            renderer's own lobes that came closer (`brdffit.export.refit`).
        fitted: the comment line naming that fit (None where ``source`` itself was mapped).
    """

    text: str
    written: object
    source: object
    notes: list
    deviation: object
    mapped: object
    fitted: str | None

    @property
    def exact(self) -> bool:
        """Whether the comments call the export exact (`brdffit.export.terms.is_exact`)."""
        from .terms import is_exact

        return is_exact(self.deviation, self.notes)

    @property
    def pairs(self):
        """The direction pairs the deviation was measured at (`brdffit.export.terms.Pairs`: uniform and near the
        peaks, with their weights): evaluate the written text there (in Mitsuba, say) to check the stated error."""
        return self.deviation.sample


def _unwrap(model_or_result):
    from ..fitting.result import FitResult
    from ..models import Model, get

    if isinstance(model_or_result, FitResult):
        return model_or_result.model, model_or_result
    if isinstance(model_or_result, Model):
        return model_or_result, None
    if isinstance(model_or_result, str):
        return get(model_or_result), None
    raise TypeError(f"export needs a brdffit Model, FitResult or spec string, got {type(model_or_result).__name__}")


def _generator() -> str:
    import brdffit

    return f"brdffit {getattr(brdffit, '__version__', 'unknown')}"


def export_details(model_or_result, to: str, *, name: str = "material", fit: bool = False,
                   wavelengths=None) -> Export:
    """`export` to a renderer, returning the written material and its measured deviation with the text.

    Arguments:
        model_or_result, name, fit, wavelengths: as `export`.
        to: a renderer in `TARGETS` (``"mitsuba"``, ``"pbrt"``, ``"gltf"``, ``"blender"``, ``"materialx"``).

    Returns:
        An `Export`.

    Raises:
        ExportError, ValueError: as `export`.
    """
    target = TARGETS.get(to)
    if target is None or not target.renderer:
        raise ValueError(f"unknown renderer {to!r}; choose one of "
                         f"{', '.join(t.name for t in TARGETS.values() if t.renderer)}")
    model, result = _unwrap(model_or_result)
    if model is None:
        raise ExportError(f"a fit in channel_mode='independent' has one model per channel ({result.spec}); "
                          f"{to} needs one material: refit with channel_mode='shared-shape' or export to json")
    header = [f"{_generator()} export of model {model.spec} to {to}"]
    if wavelengths is not None:
        from ..colour import ColourError, rgb_model

        try:
            model, line = rgb_model(model, wavelengths)
        except ColourError as exc:
            raise ExportError(f"{to} takes RGB colours, and the spectral fit has no exact RGB model: {exc}") from None
        header.append(line)
    if not fit:
        return _export(target, model, name, header, None)
    candidates = []
    try:
        candidates.append(_export(target, model, name, header, model))
    except ExportError:
        pass
    from .refit import exportable_specs, fit_exportable

    exact = bool(candidates) and candidates[0].deviation.exact()
    specs = []
    if not candidates or not (target.refines or exact):
        specs = list(target.renders) if target.family else exportable_specs(model)
    if target.refines and not exact:
        # A target that refines its own parameters (pbrt-v4) refines the mapping's materials; the models it writes
        # exactly (its coated diffuse beside its mix) are fitted to the source too, and the closest is written.
        specs += [spec for spec in target.renders if spec not in specs]
    for spec in specs:
        fitted, line = fit_exportable(model, spec=spec)
        candidates.append(_export(target, fitted, name, header, model, line))
    best = min(candidates, key=lambda c: c.deviation.rms)
    if target.approximates and not best.deviation.exact():
        fits = (fit_exportable(model, spec=spec) for spec in target.approximates)
        approximate = min((_export(target, fitted, name, header, model, line) for fitted, line in fits),
                          key=lambda c: c.deviation.rms)
        if approximate.deviation.rms <= APPROXIMATE_GAIN * best.deviation.rms:
            return approximate
    return best


def _export(target: Target, model, name: str, header: list, source, fitted: str | None = None) -> Export:
    """One renderer export of ``model``; with ``source`` (the fit option) measured against and, where the target
    refines its own parameters, refined to it; ``fitted`` is the comment line of the fit that ``model`` is."""
    lines = header + ([fitted] if fitted else [])
    text, written, notes, deviation = target.load().write(model, name, lines, source=source)
    return Export(text, written, source if source is not None else model, notes, deviation, model, fitted)


def export(model_or_result, to: str = "json", *, name: str = "material", fit: bool = False,
           wavelengths=None) -> str:
    """Write a model (or the model of a fit) in a renderer's own terms.

    Arguments:
        model_or_result: a `brdffit.Model`, a `brdffit.FitResult` or a spec string (default parameters).
        to: a name in `TARGETS`: ``"json"`` (spec, channels, parameters, plus ``stderr`` and ``status`` for a
            `FitResult`; `brdffit.models.model_from_dict` reads it back), ``"mitsuba"`` (a Mitsuba 3
            ``<bsdf version="3.0.0">`` document for ``mitsuba.load_string``), ``"pbrt"`` (pbrt-v4
            ``MakeNamedMaterial`` statements, the last one named ``name``), ``"gltf"`` (a glTF 2.0 file: the
            material on a sphere, `brdffit.export.gltf`), ``"blender"`` (a bpy script, `brdffit.export.blender`)
            or ``"materialx"`` (a MaterialX 1.39 document, `brdffit.export.materialx`).
        name: the material's id (Mitsuba) or name (pbrt).
        fit: for a renderer, fit the renderer's own model to the model over the hemisphere (cosine-weighted
            least squares: for Mitsuba a brdffit fit of lambert + GGX lobes, `brdffit.export.refit`, unless the
            direct mapping is exact; for pbrt-v4 its own parameters, refined, and fits of the models it writes
            exactly, its mix and its coated diffuse; for a target with a family of its own, its forms) and write
            the candidate closest to the model, with the achieved error in the comments (a form the target
            evaluates approximately, `Target.approximates`, only where it deviates markedly less); this also
            exports lobes with no equivalent (Oren-Nayar, Ward, Lafortune, ...). Ignored for JSON.
        wavelengths: for a spectral model (one channel per band), the bands in nm: a renderer is then given the
            model's linear sRGB equivalent (`brdffit.colour.rgb_model`: exact where every per-band parameter is an
            amplitude), and the conversion is stated in the opening comments. Ignored for JSON, which keeps the
            spectral model. ``brdffit export`` reads them from the measurements stored in the results file.

    Returns:
        The text. Renderer outputs open with comments naming the source spec, the brdffit version, each
        approximation the mapping made and the measured deviation of what is written (docs/export.md).

    Raises:
        ExportError: the model has a lobe with no equivalent in that renderer (and ``fit`` is false), more
            channels than RGB without ``wavelengths``, or a spectral model with no exact RGB model (a per-band
            parameter that is not an amplitude). ValueError: unknown format.
    """
    if to not in TARGETS:
        raise ValueError(f"unknown export format {to!r}; choose one of {', '.join(EXPORT_FORMATS)}")
    if not TARGETS[to].renderer:
        model, result = _unwrap(model_or_result)
        return TARGETS[to].load().write(model, result, _generator())
    return export_details(model_or_result, to, name=name, fit=fit, wavelengths=wavelengths).text
