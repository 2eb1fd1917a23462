"""glTF 2.0: a fitted model as a ``.gltf`` file (JSON, its buffer embedded) that any glTF viewer opens: the material
and a unit sphere that carries it.

What is written (the glTF 2.0 Specification, §5.19 "Material" and Appendix B; KHR_materials_ior,
KHR_materials_specular, KHR_materials_sheen and KHR_materials_clearcoat):

- ``pbrMetallicRoughness``: ``baseColorFactor`` (the base colour, alpha 1), ``metallicFactor``,
  ``roughnessFactor``;
- ``extensions.KHR_materials_ior.ior`` and ``extensions.KHR_materials_specular`` (``specularFactor``,
  ``specularColorFactor``), with a sheen ``extensions.KHR_materials_sheen`` (``sheenColorFactor``,
  ``sheenRoughnessFactor``) and with a clearcoat ``extensions.KHR_materials_clearcoat`` (``clearcoatFactor``,
  ``clearcoatRoughnessFactor``), listed in ``extensionsUsed`` (not ``extensionsRequired``: a viewer without them
  renders the core material, with ior 1.5, specular 1, no sheen and no coat);
- a UV sphere of radius 1 (positions, normals, indices in one base64 buffer) whose one primitive uses the material,
  in a scene of one node, so that a viewer shows the material at once;
- ``asset.extras.brdffit``: the source model, every approximation made and the measured deviation, the comments a
  JSON file cannot hold.

brdffit's ``gltf`` model is the material a glTF file describes, parameter for parameter and inside the ranges the
file accepts (`brdffit.models.gltf`), so a model that is that lobe alone is written exactly. The sheen's albedo
scaling reads a table of the sheen's directional albedo that the extension leaves to each viewer: brdffit's is
computed by quadrature (32 × 32 nodes, bilinear); a viewer's own table (the Sample Viewer's 8-bit texture) differs
from it by its resolution and precision, which the parameters written cannot carry. Any other model has no
glTF equivalent: it is refused, or under the fit option replaced by brdffit's fit of the ``gltf`` model to it
(`brdffit.export.refit`), with the achieved deviation stated.
"""

from __future__ import annotations

import base64
import json
import math

import numpy as np

from . import terms as tm

__all__ = ["write", "measured", "read_material", "sphere_mesh", "EXPORTABLE", "FAMILY"]

# The model a glTF file represents exactly (the fit option's family for this target).
FAMILY = "gltf"
EXPORTABLE = ("the gltf model alone (the glTF 2.0 metallic-roughness material with KHR_materials_ior, _specular, "
              "_sheen and _clearcoat)")
# The sphere's rings (latitude) and segments (longitude): 2,145 vertices, smooth at a viewer's default zoom.
_RINGS, _SEGMENTS = 32, 64
# glTF's component types and targets (Specification §5.1.4 "Accessor", §5.11 "Buffer View").
_FLOAT, _UNSIGNED_SHORT = 5126, 5123
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def sphere_mesh(rings: int = _RINGS, segments: int = _SEGMENTS):
    """A UV sphere of radius 1 centred at the origin, +y up (glTF's convention), counter-clockwise front faces.

    Arguments:
        rings, segments: the latitude and longitude divisions.

    Returns:
        ``(positions (V, 3) float32, normals (V, 3) float32, indices (3T,) uint16)``.
    """
    theta = np.linspace(0.0, math.pi, rings + 1)[:, None]
    phi = np.linspace(0.0, 2.0 * math.pi, segments + 1)[None, :]
    x, y, z = np.sin(theta) * np.sin(phi), np.cos(theta) * np.ones_like(phi), np.sin(theta) * np.cos(phi)
    positions = np.stack([x, y, z], axis=-1).reshape(-1, 3).astype(np.float32)
    normals = positions / np.linalg.norm(positions, axis=1, keepdims=True)
    row = segments + 1
    quads = [(r * row + s, (r + 1) * row + s, (r + 1) * row + s + 1, r * row + s + 1)
             for r in range(rings) for s in range(segments)]
    # Each quad as two triangles, wound counter-clockwise seen from outside; the poles' degenerate ones dropped.
    triangles = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))
                 if len({tuple(positions[i]) for i in t}) == 3]
    return positions, normals.astype(np.float32), np.asarray(triangles, dtype=np.uint16).ravel()


def _has_sheen(values: dict) -> bool:
    """Whether the material has a sheen (KHR_materials_sheen: a sheenColorFactor of zero disables the layer)."""
    return max(values["sheen_color"]) > 0


def _document(values: dict, name: str, extras: dict) -> dict:
    """The glTF JSON of the material on a sphere."""
    positions, normals, indices = sphere_mesh()
    blobs = [positions.tobytes(), normals.tobytes(), indices.tobytes()]
    offsets = np.cumsum([0] + [len(b) for b in blobs])[:-1]
    buffer = b"".join(blobs)
    return {
        "asset": {"version": "2.0", "generator": extras["generator"], "extras": {"brdffit": extras}},
        "extensionsUsed": ["KHR_materials_ior", "KHR_materials_specular"]
        + (["KHR_materials_sheen"] if _has_sheen(values) else [])
        + (["KHR_materials_clearcoat"] if values["clearcoat"] > 0 else []),
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0]}],
        "nodes": [{"name": f"{name} sphere", "mesh": 0}],
        "meshes": [{"name": f"{name} sphere",
                    "primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "materials": [{
            "name": name,
            "pbrMetallicRoughness": {"baseColorFactor": values["base_color"] + [1.0],
                                     "metallicFactor": values["metallic"], "roughnessFactor": values["roughness"]},
            "extensions": {"KHR_materials_ior": {"ior": values["ior"]},
                           "KHR_materials_specular": {"specularFactor": values["specular"],
                                                      "specularColorFactor": values["specular_color"]},
                           **({"KHR_materials_sheen": {"sheenColorFactor": values["sheen_color"],
                                                       "sheenRoughnessFactor": values["sheen_roughness"]}}
                              if _has_sheen(values) else {}),
                           **({"KHR_materials_clearcoat": {
                               "clearcoatFactor": values["clearcoat"],
                               "clearcoatRoughnessFactor": values["clearcoat_roughness"]}}
                              if values["clearcoat"] > 0 else {})},
        }],
        "accessors": [
            {"bufferView": 0, "componentType": _FLOAT, "count": len(positions), "type": "VEC3",
             "min": [float(v) for v in positions.min(axis=0)], "max": [float(v) for v in positions.max(axis=0)]},
            {"bufferView": 1, "componentType": _FLOAT, "count": len(normals), "type": "VEC3"},
            {"bufferView": 2, "componentType": _UNSIGNED_SHORT, "count": len(indices), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": int(offsets[0]), "byteLength": len(blobs[0]), "target": _ARRAY_BUFFER},
            {"buffer": 0, "byteOffset": int(offsets[1]), "byteLength": len(blobs[1]), "target": _ARRAY_BUFFER},
            {"buffer": 0, "byteOffset": int(offsets[2]), "byteLength": len(blobs[2]),
             "target": _ELEMENT_ARRAY_BUFFER},
        ],
        "buffers": [{"byteLength": len(buffer),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer).decode("ascii")}],
    }


def measured(model: tm.Model, source=None):
    """The glTF material of ``model`` and its deviation from ``source`` (default ``model``), for every target that
    writes the glTF material (this file, MaterialX's ``gltf_pbr``): `brdffit.export.terms.own_model` for the
    ``gltf`` lobe."""
    return tm.own_model(model, FAMILY, "glTF", EXPORTABLE, source)


def write(model: tm.Model, name: str, header: list[str], source=None):
    """The glTF file of ``model``.

    Arguments:
        model: a model that is brdffit's ``gltf`` lobe alone (1 or 3 channels).
        name: the material's (and the scene's) name.
        header: lines naming the source and the brdffit version (and the fit, under the fit option); the first
            names the generator.
        source: the model the deviation is measured against (the original under the fit option); default
            ``model``.

    Returns:
        (text, a function (wi, wo) -> f_r of the written material, notes, `Deviation` from the source).

    Raises:
        ExportError: a model other than the ``gltf`` lobe alone, or a channel count other than 1 or 3.
    """
    values, written, deviation = measured(model, source)
    notes: list[str] = []
    from . import _generator

    extras = {"generator": _generator(), "comments": tm.stated(header, notes, deviation),
              "source": (model if source is None else source).spec}
    text = json.dumps(_document(values, name, extras), indent=1) + "\n"
    return text, written, notes, deviation


def read_material(text: str) -> dict:
    """The material of a glTF file this module wrote, as the ``gltf`` model's parameters (a check that what was
    written is what was meant; a viewer reads the same fields)."""
    material = json.loads(text)["materials"][0]
    core, ext = material["pbrMetallicRoughness"], material.get("extensions", {})
    coat, sheen = ext.get("KHR_materials_clearcoat", {}), ext.get("KHR_materials_sheen", {})
    return {"base_color": core["baseColorFactor"][:3], "metallic": core.get("metallicFactor", 1.0),
            "roughness": core.get("roughnessFactor", 1.0), "ior": ext.get("KHR_materials_ior", {}).get("ior", 1.5),
            "specular": ext.get("KHR_materials_specular", {}).get("specularFactor", 1.0),
            "specular_color": ext.get("KHR_materials_specular", {}).get("specularColorFactor", [1.0, 1.0, 1.0]),
            "sheen_color": sheen.get("sheenColorFactor", [0.0, 0.0, 0.0]),
            "sheen_roughness": sheen.get("sheenRoughnessFactor", 0.0),
            "clearcoat": coat.get("clearcoatFactor", 0.0),
            "clearcoat_roughness": coat.get("clearcoatRoughnessFactor", 0.0)}

