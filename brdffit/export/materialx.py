"""MaterialX 1.39: a fitted model as a MaterialX document with three materials, the glTF material and its OpenPBR
Surface and Autodesk Standard Surface counterparts.

What is written (MaterialX 1.39's standard data libraries, ``libraries/bxdf``):

- ``<gltf_pbr>`` (``ND_gltf_pbr_surfaceshader``) with ``base_color``, ``metallic``, ``roughness``, ``specular``,
  ``specular_color``, ``ior``, ``sheen_color``, ``sheen_roughness``, ``clearcoat`` and ``clearcoat_roughness``: the
  glTF 2.0 material, parameter for parameter, in the material ``<surfacematerial name=NAME>``. Its sheen is not
  KHR_materials_sheen's BRDF exactly: the node's graph (``libraries/bxdf/gltf_pbr.mtlx``) layers a ``sheen_bsdf`` in
  its default ``conty_kulla`` mode, whose shader code (``pbrlib/genglsl/lib/mx_microfacet_sheen.glsl``) has the
  Charlie distribution but Neubelt and Pettineo's visibility 1/(4 (n·l + n·v − (n·l)(n·v))) in place of the Charlie
  visibility, and scales the layers beneath by 1 − max(sheen_color) E(n·v) alone (E that BRDF's albedo, a fit)
  where the extension takes the smaller of the weights at n·v and n·l; a document with a sheen states this
  approximation;
- ``<open_pbr_surface>`` (``ND_open_pbr_surface_surfaceshader``, OpenPBR Surface 1.x) with the same values under
  OpenPBR's names (``base_color``, ``base_metalness``, ``specular_roughness``, ``specular_ior``,
  ``specular_weight``, ``specular_color``, ``coat_weight``, ``coat_roughness``, and a sheen as ``fuzz_weight`` =
  max(sheen_color), ``fuzz_color`` = sheen_color/max(sheen_color), ``fuzz_roughness`` = sheen_roughness, the split
  MaterialX's gltf_pbr graph makes), in ``<surfacematerial name=NAME_openpbr>``: the mapping from glTF that
  the OpenPBR specification gives for its metallic-roughness subset. OpenPBR layers the specular over the diffuse
  by the layer's directional albedo and evaluates an F82-tinted conductor, where glTF mixes per direction by
  Schlick's Fresnel term, so this one is an approximation, stated as such;
- ``<standard_surface>`` (``ND_standard_surface_surfaceshader``) in ``<surfacematerial name=NAME_standard>``, with
  the values that MaterialX's own translation graph ``ND_standard_surface_to_gltf_pbr``
  (``libraries/bxdf/translation/standard_surface_to_gltf_pbr.mtlx``) carries back to the glTF values: ``base`` 1,
  ``base_color``, ``metalness``, ``specular``, ``specular_color``, ``specular_roughness``, ``specular_IOR``,
  ``coat`` with ``coat_color`` white and ``coat_roughness``, ``sheen`` = max(sheen_color), ``sheen_color`` =
  sheen_color/max(sheen_color) and ``sheen_roughness`` = sheen_roughness² (the graph takes its square root).
  Standard Surface layers its lobes by albedo, as OpenPBR does, and its sheen is its own: an approximation,
  stated as such;
- comments: the source, the version, the approximations and the measured deviation of the glTF material.

The written glTF material is brdffit's ``gltf`` model, so its deviation is measured exactly as for the glTF export
(`brdffit.export.gltf`): a model that is that lobe alone is written exactly, any other is refused or, under the
fit option, replaced by the ``gltf`` model fitted to it. MaterialX's own ``gltf_pbr`` graph is its renderers'
reading of the same material (it layers, as OpenPBR does); brdffit has no MaterialX evaluator, so the difference
between a MaterialX renderer's result and Appendix B is not measured here (docs/export.md).
"""

from __future__ import annotations

from xml.sax.saxutils import escape, quoteattr

import numpy as np

from ..models.openpbr import OpenPBR
from . import gltf
from . import terms as tm

__all__ = ["write", "document", "identifier", "OPENPBR_NAMES", "STANDARD_SURFACE_NAMES", "EXPORTABLE"]

EXPORTABLE = gltf.EXPORTABLE
# The gltf model's parameters -> OpenPBR Surface's inputs (its metallic-roughness subset).
OPENPBR_NAMES = {"base_color": "base_color", "metallic": "base_metalness", "roughness": "specular_roughness",
                 "ior": "specular_ior", "specular": "specular_weight", "specular_color": "specular_color",
                 "clearcoat": "coat_weight", "clearcoat_roughness": "coat_roughness"}
# The gltf model's parameters -> Standard Surface's inputs: the inverse of MaterialX's translation graph
# ND_standard_surface_to_gltf_pbr, where it renames (the sheen is split and squared by `_standard_surface`).
STANDARD_SURFACE_NAMES = {"base_color": "base_color", "metallic": "metalness", "roughness": "specular_roughness",
                          "ior": "specular_IOR", "specular": "specular", "specular_color": "specular_color",
                          "clearcoat": "coat", "clearcoat_roughness": "coat_roughness"}
# KHR_materials_clearcoat's index of refraction, written as the OpenPBR coat's.
CLEARCOAT_IOR = 1.5
# The sheen's parameters, written to OpenPBR's fuzz by `_openpbr` and Standard Surface's sheen by
# `_standard_surface` (a split, not a renaming).
_SHEEN = ("sheen_color", "sheen_roughness")


def _openpbr(values: dict) -> dict:
    """OpenPBR Surface's inputs for the glTF values: renamed by `OPENPBR_NAMES`; a clearcoat as a coat of index
    1.5 (KHR_materials_clearcoat's, where OpenPBR's default is 1.6); a sheen as fuzz (weight the sheen colour's
    largest channel, colour the sheen colour divided by it, roughness the sheen's)."""
    inputs = {OPENPBR_NAMES[k]: v for k, v in values.items() if k not in _SHEEN}
    if values["clearcoat"] > 0:
        inputs["coat_ior"] = CLEARCOAT_IOR
    strength, colour = _split_sheen(values)
    if strength > 0:
        inputs.update(fuzz_weight=strength, fuzz_color=colour, fuzz_roughness=values["sheen_roughness"])
    return inputs


def _openpbr_deviation(values: dict, reference: tm.Model):
    """The measured deviation from ``reference`` of the OpenPBR counterpart of the glTF values (`_openpbr`), read as
    brdffit's ``openpbr`` model (`brdffit.models.openpbr`, OpenPBR Surface as MaterialX evaluates it, with its coat
    for a clearcoat and its fuzz for a sheen)."""
    inputs = _openpbr(values)
    coated = values["clearcoat"] > 0
    if not coated:
        inputs = {k: v for k, v in inputs.items() if k not in ("coat_weight", "coat_roughness")}
    inputs["base_diffuse_roughness"] = 0.0
    lobe = OpenPBR(coat=coated, fuzz="fuzz_weight" in inputs)
    counterpart = tm.assemble([(lobe, {k: np.asarray(v, dtype=float) for k, v in inputs.items()})], 3)
    return tm.measure(reference, counterpart, pairs=tm.deviation_pairs(tm.peaks(reference, counterpart)))


def _split_sheen(values: dict) -> tuple:
    """The sheen colour as (weight, colour): its largest channel and the colour divided by it ((0, None) for no
    sheen), the split MaterialX's translation graphs make."""
    strength = max(values["sheen_color"])
    return (strength, [c / strength for c in values["sheen_color"]]) if strength > 0 else (0.0, None)


def _standard_surface(values: dict) -> dict:
    """Standard Surface's inputs for the glTF values: the ones MaterialX's ND_standard_surface_to_gltf_pbr
    translates back to them (module doc)."""
    inputs = {"base": 1.0}
    inputs.update({STANDARD_SURFACE_NAMES[k]: v for k, v in values.items() if k not in _SHEEN})
    inputs["coat_color"] = [1.0, 1.0, 1.0]  # white: the graph's clearcoat is then the coat weight itself
    strength, colour = _split_sheen(values)
    if strength > 0:
        inputs.update(sheen=strength, sheen_color=colour, sheen_roughness=values["sheen_roughness"] ** 2)
    return inputs


def _input(name: str, value) -> str:
    if isinstance(value, list):
        return f'    <input name="{name}" type="color3" value="{", ".join(tm.number(v) for v in value)}" />'
    return f'    <input name="{name}" type="float" value="{tm.number(value)}" />'


def _shader(node: str, shader: str, material: str, inputs: dict) -> list[str]:
    lines = [f"  <{node} name={quoteattr(shader)} type=\"surfaceshader\">"]
    lines += [_input(name, value) for name, value in inputs.items()]
    lines += [f"  </{node}>",
              f"  <surfacematerial name={quoteattr(material)} type=\"material\">",
              f'    <input name="surfaceshader" type="surfaceshader" nodename={quoteattr(shader)} />',
              "  </surfacematerial>"]
    return lines


def identifier(name: str) -> str:
    """A valid MaterialX element name (letters, digits and underscores, not starting with a digit)."""
    cleaned = "".join(c if c.isalnum() or c == "_" else "_" for c in name) or "material"
    return cleaned if not cleaned[0].isdigit() else "M_" + cleaned


def document(comments: list[str], materials: list[tuple]) -> str:
    """A MaterialX 1.39 document (colour space lin_rec709): the comment lines, then for each ``(node, material,
    inputs)`` a shader node ``SR_<material>`` of that node with those inputs (floats, or RGB lists as color3) and
    its ``<surfacematerial name=material>``."""
    lines = ['<?xml version="1.0"?>', '<materialx version="1.39" colorspace="lin_rec709">']
    lines += [f"  <!-- {escape(line).replace('--', '- -')} -->" for line in comments]
    for node, material, inputs in materials:
        lines += _shader(node, f"SR_{material}", material, inputs)
    lines.append("</materialx>")
    return "\n".join(lines) + "\n"


def write(model: tm.Model, name: str, header: list[str], source=None):
    """The MaterialX document of ``model``.

    Arguments:
        model: a model that is brdffit's ``gltf`` lobe alone (1 or 3 channels).
        name: the glTF material's name (made a valid MaterialX name); the OpenPBR one is ``NAME_openpbr``, the
            Standard Surface one ``NAME_standard``.
        header: comment lines (source, version, fit).
        source: the model the deviation is measured against (the original under the fit option).

    Returns:
        (text, a function (wi, wo) -> f_r of the glTF material written, notes (the OpenPBR and Standard Surface
        approximations),
        `Deviation` of the glTF material from the source).

    Raises:
        ExportError: a model other than the ``gltf`` lobe alone, or a channel count other than 1 or 3.
    """
    values, written, deviation = gltf.measured(model, source)
    material = identifier(name)
    counterpart = _openpbr_deviation(values, model if source is None else source)
    measured = "brdffit's openpbr model measures its deviation from the source: " + counterpart.describe()
    notes = [f"{material}_openpbr (open_pbr_surface) takes the glTF values under OpenPBR's names; OpenPBR layers the "
             "specular over the diffuse by albedo and tints its conductor by F82, where glTF mixes by Schlick's "
             f"Fresnel per direction: {measured} (the deviation below is the glTF material's, {material})",
             f"{material}_standard (standard_surface) takes the values that MaterialX's translation graph "
             "standard_surface_to_gltf_pbr carries back to the glTF ones; Standard Surface layers its lobes by "
             "albedo and has its own sheen: its deviation is not measured"]
    if max(values["sheen_color"]) > 0:
        notes.append(f"{material} (gltf_pbr): MaterialX's sheen_bsdf (conty_kulla) takes the Charlie distribution "
                     "with Neubelt and Pettineo's visibility 1/(4 (n.l + n.v - n.l n.v)) instead of the Charlie "
                     "visibility of KHR_materials_sheen, and scales the base by 1 - max(sheen_color) E(n.v) at the "
                     "view alone: its sheen is not measured (the deviation below is brdffit's glTF material's); "
                     f"{material}_openpbr writes the sheen as OpenPBR's fuzz (Zeltner et al.'s LTC sheen)")
    text = document(tm.stated(header, notes, deviation),
                    [("gltf_pbr", material, values), ("open_pbr_surface", f"{material}_openpbr", _openpbr(values)),
                     ("standard_surface", f"{material}_standard", _standard_surface(values))])
    return text, written, notes, deviation
