"""The abstract lobe: one reflection term with declared parameters and a pure evaluation.

A lobe is a small immutable value (its fields are options such as the microfacet distribution), hashable so that
it can sit in a model's static structure. Concrete lobes fill `name`, declare their parameters in `param_specs`,
evaluate in `__call__`, and override the hooks declared here (start candidates, canonical order, amplitude
partners, peaks) where they have them.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

from ..geometry import LocalPair
from ..params import ParamSpec

__all__ = ["Lobe", "COMMON_OPTIONS"]

# The options every lobe has (the base class's fields), described once in docs/models.md.
COMMON_OPTIONS = ("share", "bounded")


@dataclasses.dataclass(frozen=True)
class Lobe(abc.ABC):
    """Abstract base of every lobe.

    Subclasses are frozen dataclasses whose fields are the lobe's options, and they provide:

    - ``name``: the registry name (``"cook-torrance"``);
    - ``reference``: the paper the formula comes from;
    - ``reciprocal``: whether f(ωi, ωo) = f(ωo, ωi) holds for every parameter value;
    - ``offset``: whether part of the value does not scale with the linear amplitudes (affine, not linear, in
      them: Ashikhmin-Shirley's Fresnel term rs + (1 − rs)(1 − h·k)⁵); False for most lobes, whose value is zero
      with every amplitude at zero, so that the separable solve does not evaluate them there
      (`brdffit.fitting.separable.amplitude_basis`);
    - ``stand_in``: the lobes of Mitsuba 3's exact family (``lambert`` and GGX lobes) that the export's fit option
      fits in place of this lobe (`brdffit.export.refit.exportable_spec`), where one GGX lobe with the lobe's own
      Fresnel term (None, the default) would miss a part of it: ``"lambert"`` for a diffuse lobe, a lambert beside
      the GGX lobe for a renderer's material with a diffuse base (glTF's, Blender's, the principled BRDF, pbrt-v4's
      mix);
    - ``param_specs()``: the parameter declarations, in order;
    - ``__call__(params, pair)``: the BRDF value in 1/sr, without the cosine factor;
    - ``peaks(params)``, where the lobe has highlights: where they are (`brdffit.models.peaks.Peak`); none for a
      diffuse lobe;
    - ``layers``: for a lobe with options that add a layer (a coat, a sheen), each such option's name and the
      parameter whose value 0 removes the layer, which then leaves the lobe without that option (`nested`).

    Every lobe has two options of its own, declared here once (`COMMON_OPTIONS`):

    - ``share``: the names of parameters that this lobe takes from the nearest earlier lobe of the sum declaring
      them, instead of having its own (space-separated: ``"lambert+ggx+ggx(share=f0)"`` is two GGX lobes with one
      Fresnel term). The model's `Layout` resolves it; amplitudes cannot be shared.
    - ``bounded``: every amplitude the lobe declares without an upper bound (ks) is bounded by 1, so that ks·F ≤ 1
      where its Fresnel factor reaches 1 (`brdffit.plausibility.plausibility`'s specular check holds by
      construction): ``"lambert+ggx(bounded=true)"`` is the best fit a renderer can take as physically
      plausible, where the unbounded one needs ks > 1 to follow the data. The `Layout` applies it.
    """

    name: ClassVar[str]
    reference: ClassVar[str]
    reciprocal: ClassVar[bool] = True
    offset: ClassVar[bool] = False
    stand_in: ClassVar[str | None] = None
    layers: ClassVar[dict[str, str]] = {}

    share: str = ""
    bounded: bool = False

    @property
    def shared(self) -> tuple[str, ...]:
        """The local names this lobe takes from an earlier lobe (the ``share`` option, split)."""
        return tuple(str(self.share).split())

    @classmethod
    def option_names(cls) -> tuple[str, ...]:
        """Names of the options this lobe accepts (its dataclass fields)."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def options(self) -> dict:
        """The option values of this lobe, as a dict."""
        return {name: getattr(self, name) for name in self.option_names()}

    def token(self) -> str:
        """The spec token of this lobe: its name, with its non-default options in brackets (``share`` last)."""
        defaults = type(self)()
        options = sorted(self.options().items(), key=lambda item: item[0] == "share")
        changed = [f"{k}={v}" for k, v in options if getattr(defaults, k) != v]
        return self.name + (f"({', '.join(changed)})" if changed else "")

    def nested(self) -> list[tuple[Lobe, dict]]:
        """The forms of this lobe that it contains, one layer fewer each: ``(form, values)`` for every layer option
        that is on (`layers`), ``values`` the local parameter values (the layer's weight at 0) at which this lobe
        is that form. A fit of this lobe can start from a fit of the form (`brdffit.select`)."""
        return [(dataclasses.replace(self, **{option: False}), {weight: 0.0})
                for option, weight in self.layers.items() if getattr(self, option)]

    def start_candidates(self) -> list[dict]:
        """Starting values of shape parameters (local names) worth trying first; the initial guess adds them to
        its grid. Lobes with several similar sub-lobes use this to start them apart. Default: none."""
        return []

    def sub_lobe_candidates(self, amplitude: str, params: dict) -> list[dict]:
        """Settings of the shape of the sub-lobe scaled by ``amplitude`` (local names, of its
        `amplitude_partners`) worth trying when a fit searches that sub-lobe again with the rest of the model held
        (`brdffit.fitting.api`'s lobe re-search), at the lobe's current ``params`` (local names): shapes that a
        grid over each parameter's range cannot hit. Default: none."""
        return []

    def amplitude_partners(self, amplitude: str) -> tuple[str, ...]:
        """Local names of the parameters that act only through the amplitude ``amplitude`` (its sub-lobe's shape):
        when the amplitude is 0 they are undetermined. Default: every other parameter of the lobe, or none for a
        lobe with an ``offset`` (a part that does not vanish with its amplitudes still reads them: Ashikhmin-
        Shirley's grazing Fresnel term, the specular layers over a renderer material's base colour)."""
        if self.offset:
            return ()
        return tuple(spec.name for spec in self.param_specs() if spec.name != amplitude)

    def peaks(self, params: dict) -> tuple:
        """Where the lobe peaks at these parameter values (local names), as `brdffit.models.peaks.Peak` values
        (their ``lobe`` left empty), for the export's deviation pairs to draw directions there. Default: none (a
        diffuse lobe; uniform pairs cover it)."""
        return ()

    def canonical(self, params: dict) -> dict:
        """The same lobe with its parameters in canonical order (e.g. sub-lobes sorted), so that equivalent
        solutions are reported one way. Default: unchanged."""
        return params

    @abc.abstractmethod
    def param_specs(self) -> tuple[ParamSpec, ...]:
        """The parameter declarations of this lobe with its local names."""

    @abc.abstractmethod
    def __call__(self, params: dict, pair: LocalPair):
        """Evaluate the lobe.

        Arguments:
            params: local parameter name -> value; colour parameters have shape ``(C,)``, shape parameters are
                scalars.
            pair: the shared direction quantities (`brdffit.geometry.LocalPair`), leading shape ``S``.

        Returns:
            Array broadcastable to ``S + (C,)``, in 1/sr. Values below the horizon are masked by the caller.
        """
