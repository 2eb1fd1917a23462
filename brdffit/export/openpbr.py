"""OpenPBR Surface: a fitted model as a MaterialX 1.39 document with one ``open_pbr_surface``.

The document holds one material, ``<surfacematerial name=NAME>``, whose shader is MaterialX's
``open_pbr_surface`` node (``ND_open_pbr_surface_surfaceshader``, OpenPBR Surface 1.1) with brdffit's ``openpbr``
model's values under the node's own names (``base_color``, ``base_metalness``, ``base_diffuse_roughness``,
``specular_weight``, ``specular_color``, ``specular_roughness``, ``specular_ior``; ``coat_weight``, ``coat_color``,
``coat_roughness``, ``coat_ior``, ``coat_darkening`` for a model with a coat; ``fuzz_weight``, ``fuzz_color``,
``fuzz_roughness`` for one with fuzz) and the inputs the model holds written out at the values it assumes
(``base_weight`` 1, ``specular_roughness_anisotropy``, ``coat_weight`` and ``fuzz_weight`` (without them),
``thin_film_weight``, ``transmission_weight``, ``subsurface_weight`` and ``emission_luminance`` 0), so that another
default in a later OpenPBR version does not change the material. brdffit's ``openpbr`` model
is that node as MaterialX's GLSL evaluates it (`brdffit.models.openpbr`), so a model that is that lobe alone is
written exactly; any other is refused or, under the fit option, replaced by the closest of the target's forms of
the ``openpbr`` model fitted to it (with and without coat and fuzz), with the measured deviation stated in the
document's comments.
"""

from __future__ import annotations

from . import terms as tm
from .materialx import document, identifier

__all__ = ["write", "FAMILY", "EXPORTABLE", "HELD"]

FAMILY = "openpbr"
EXPORTABLE = "the openpbr model alone (OpenPBR Surface as MaterialX evaluates it)"
# The node's inputs that the model holds, at the values it assumes (a model with a coat or fuzz writes its own
# weight).
HELD = {"base_weight": 1.0, "specular_roughness_anisotropy": 0.0, "coat_weight": 0.0, "fuzz_weight": 0.0,
        "thin_film_weight": 0.0, "transmission_weight": 0.0, "subsurface_weight": 0.0, "emission_luminance": 0.0}


def write(model: tm.Model, name: str, header: list[str], source=None):
    """The MaterialX document of ``model``'s OpenPBR Surface.

    Arguments:
        model: a model that is brdffit's ``openpbr`` lobe alone, with or without coat and fuzz (1 or 3 channels).
        name: the material's name (made a valid MaterialX name; the shader node is ``SR_<name>``).
        header: comment lines (source, version, fit).
        source: the model the deviation is measured against (the original under the fit option).

    Returns:
        (text, a function (wi, wo) -> f_r of the material written, notes, `Deviation` from the source).

    Raises:
        ExportError: a model other than the ``openpbr`` lobe alone, or a channel count other than 1 or 3.
    """
    values, written, deviation = tm.own_model(model, FAMILY, "OpenPBR", EXPORTABLE, source)
    notes: list[str] = []
    text = document(tm.stated(header, notes, deviation),
                    [("open_pbr_surface", identifier(name), {**HELD, **values})])
    return text, written, notes, deviation
