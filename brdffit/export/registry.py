"""The export targets as values (light: the CLI builds its ``--to`` choices from it without loading JAX)."""

from __future__ import annotations

import dataclasses
import importlib

__all__ = ["ExportError", "Target", "TARGETS", "EXPORT_FORMATS", "FIT_TARGETS", "APPROXIMATE_GAIN"]

# An approximate form (`Target.approximates`) replaces the best exact one under the fit option only where its
# deviation is at most this fraction of that one's: the approximate forms nest the exact ones, so they always
# deviate a little less, and a trace of sheen is not worth a material that the renderer evaluates otherwise.
APPROXIMATE_GAIN = 0.9


class ExportError(ValueError):
    """The model has no equivalent in the requested format (the message names the lobe)."""


@dataclasses.dataclass(frozen=True)
class Target:
    """An export format.

    Attributes:
        name: the ``to=`` / ``--to`` name.
        description: one line for help texts.
        module: the module of `brdffit.export` that writes it; a renderer's module has
            ``write(model, name, header, source=None) -> (text, written, notes, deviation)``, where under the fit
            option ``source`` is the original model that the deviation is measured against.
        renderer: False for brdffit's own JSON (`brdffit.export.native`, which also takes fits with one model
            per channel).
        refines: whether ``write`` with a ``source`` fits the renderer's own parameters to it (pbrt-v4); a target
            that does not (Mitsuba 3, whose plugins brdffit's lambert + GGX lobes are exactly) gets a brdffit fit
            of those lobes (`brdffit.export.refit`) unless its direct mapping is exact.
        family: the brdffit lobe the target writes exactly and alone (glTF: ``gltf``), whose ``renders`` forms
            the fit option fits in place of any other model (the one of least deviation is written); empty for a
            target whose fit option fits `brdffit.export.refit`'s lambert + GGX families.
        renders: the brdffit models the target writes exactly with every parameter inside the ranges its own
            tools accept (no unbounded values, no blends): the candidates of a fit for the target
            (`brdffit.select`'s ``target``, ``brdffit fit --for``), and, for a target with a ``family`` or one that
            ``refines``, of the fit option (`brdffit.export.export_details`); empty where none is declared yet.
        approximates: the brdffit models the target writes in its ranges but evaluates approximately (each export
            of one states the approximation): not candidates of a fit for the target, but of the fit option, where
            one is written only if its deviation is below `APPROXIMATE_GAIN` times the best exact form's.
    """

    name: str
    description: str
    module: str
    renderer: bool = True
    refines: bool = False
    family: str = ""
    renders: tuple = ()
    approximates: tuple = ()

    def load(self):
        """The target's module (imported on first use)."""
        return importlib.import_module(f"{__package__}.{self.module}")


TARGETS = {t.name: t for t in (
    Target("json", "brdffit's own description (model_from_dict reads it back)", "native", renderer=False),
    Target("mitsuba", "a Mitsuba 3 <bsdf version=\"3.0.0\"> document", "mitsuba",
           renders=("lambert", "principled", "roughplastic", "ggx(fresnel=conductor, bounded=true)")),
    Target("pbrt", "pbrt-v4 MakeNamedMaterial statements", "pbrt", refines=True,
           renders=("pbrt", "coateddiffuse", "coatedconductor")),
    Target("gltf", "a glTF 2.0 .gltf file: the material (with KHR_materials_ior, _specular, _sheen, _clearcoat) on a "
                   "sphere",
           "gltf", family="gltf", renders=("gltf",)),
    Target("blender", "a Python script that builds the material (Principled BSDF, GGX) with bpy, Blender 4.2+",
           "blender", family="blender", renders=("blender", "blender(coat=true)"),
           approximates=("blender(coat=true, sheen=true)",)),
    Target("materialx", "a MaterialX 1.39 document: the glTF material (gltf_pbr) and its OpenPBR Surface and "
           "Standard Surface counterparts", "materialx", family="gltf", renders=("gltf",)),
    Target("openpbr", "a MaterialX 1.39 document with one OpenPBR Surface (open_pbr_surface) as MaterialX evaluates "
           "it", "openpbr", family="openpbr",
           renders=("openpbr", "openpbr(fuzz=true)", "openpbr(coat=true)", "openpbr(coat=true, fuzz=true)")),
)}
EXPORT_FORMATS = tuple(TARGETS)
# The targets a fit can be made for (`brdffit fit --for`): those with models declared exact and in range.
FIT_TARGETS = tuple(name for name, target in TARGETS.items() if target.renders)
