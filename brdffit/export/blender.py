"""Blender 4.2+: a fitted model as a Python script that builds the material's node tree with ``bpy``.

The script makes a material of one ``Principled BSDF`` node (distribution ``GGX``) feeding the ``Material Output``:
``Base Color``, ``Metallic``, ``Roughness`` and ``IOR`` from brdffit's ``blender`` model (and ``Coat Weight``,
``Coat Roughness``, ``Coat IOR``, ``Coat Tint`` from a model with a coat, ``Sheen Weight``, ``Sheen Tint``,
``Sheen Roughness`` from one with a sheen), every other input at its neutral value (``Specular IOR Level`` 0.5,
``Specular Tint`` white, no subsurface, sheen, coat, transmission or emission). brdffit's ``blender`` model is that
node as Cycles evaluates it (`brdffit.models.blender`), so a model that is that lobe alone is written exactly, but
for a sheen, which Cycles evaluates from a table that the model approximates by MaterialX's fits (stated as an
approximation, `SHEEN_NOTE`); any other model is refused or, under the fit option, replaced by the closest of the
target's forms fitted to it, with the measured deviation stated in the script's comments.

Two settings make Cycles evaluate the node as the model does, and the script sets them: the ``GGX`` distribution
(Blender's default, ``Multiscatter GGX``, adds an energy-compensation term the single-scattering model has not), and
``use_bump_map_correction`` off (on smooth-shaded faces Cycles otherwise bends the specular normal towards the
face's flat normal near grazing views).

Run it in Blender's Text Editor or Python console, with ``blender --python FILE``, or with ``python FILE`` where
the ``bpy`` module is installed (PyPI ``bpy``, brdffit's ``blender`` extra): it builds the material, assigns it to
the active mesh object if there is one, and prints its name. ``build_material(name)`` is importable.
"""

from __future__ import annotations

from . import terms as tm

__all__ = ["write", "FAMILY", "EXPORTABLE", "NODE_INPUTS", "SHEEN_NOTE"]

FAMILY = "blender"
EXPORTABLE = "the blender model alone (Blender's Principled BSDF with the GGX distribution)"
# The blender model's parameters -> the Principled BSDF's inputs.
NODE_INPUTS = {"base_color": "Base Color", "metallic": "Metallic", "roughness": "Roughness", "ior": "IOR",
               "coat_weight": "Coat Weight", "coat_roughness": "Coat Roughness", "coat_ior": "Coat IOR",
               "coat_tint": "Coat Tint", "sheen_weight": "Sheen Weight", "sheen_tint": "Sheen Tint",
               "sheen_roughness": "Sheen Roughness"}
# What a sheen costs: brdffit's blender model evaluates MaterialX's fits of Zeltner's LTC (`brdffit.models.sheen`),
# Cycles its own table of the same quantities, which bpy does not ship (docs/export.md has the measured differences).
SHEEN_NOTE = ("the sheen: Cycles reads Zeltner's LTC and its albedo from its own table, brdffit (and the deviation "
              "below) from MaterialX's fits of them; Cycles renders of a sheen alone differ by 1-10% (most at sheen "
              "roughness 0.3-0.5), of a sheen over a diffuse base by less (docs/export.md)")
# The inputs held at their neutral values (Blender 4.2's names); a model with a coat writes its own Coat Weight.
_NEUTRAL = {"Specular IOR Level": 0.5, "Specular Tint": (1.0, 1.0, 1.0, 1.0), "Anisotropic": 0.0,
            "Subsurface Weight": 0.0, "Transmission Weight": 0.0, "Coat Weight": 0.0, "Sheen Weight": 0.0,
            "Emission Strength": 0.0, "Alpha": 1.0}


def _value(value) -> str:
    if isinstance(value, tuple):
        return "(" + ", ".join(tm.number(v) for v in value) + ")"
    return tm.number(value)


def write(model: tm.Model, name: str, header: list[str], source=None):
    """The Blender script of ``model``.

    Arguments:
        model: a model that is brdffit's ``blender`` lobe alone (1 or 3 channels).
        name: the material's name.
        header: comment lines (source, version, fit).
        source: the model the deviation is measured against (the original under the fit option).

    Returns:
        (text, a function (wi, wo) -> f_r of the material written, notes, `Deviation` from the source).

    Raises:
        ExportError: a model other than the ``blender`` lobe alone, or a channel count other than 1 or 3.
    """
    values, written, deviation = tm.own_model(model, FAMILY, "Blender", EXPORTABLE, source)
    values = {k: (tuple(v) if isinstance(v, list) else v) for k, v in values.items()}
    notes: list[str] = []
    if values.get("sheen_weight", 0.0) > 0.0 and max(values.get("sheen_tint", (1.0,))) > 0.0:
        notes.append(SHEEN_NOTE)
    inputs = dict(_NEUTRAL)
    inputs.update({NODE_INPUTS[k]: (v + (1.0,) if isinstance(v, tuple) else v) for k, v in values.items()})
    lines = [f"# {line}" for line in tm.stated(header, notes, deviation)]
    lines += [
        '"""The brdffit material as a Blender (4.2+) Principled BSDF: run in Blender, with `blender --python FILE`,',
        'or `python FILE` with the bpy module; see brdffit\'s docs/export.md."""',
        "import bpy",
        "",
        f"NAME = {name!r}",
        "INPUTS = {",
        *[f"    {key!r}: {_value(value)}," for key, value in inputs.items()],
        "}",
        "",
        "",
        "def build_material(name=NAME):",
        '    """A new material NAME: one Principled BSDF (GGX) with INPUTS, into the Material Output."""',
        "    material = bpy.data.materials.new(name)",
        "    material.use_nodes = True",
        "    material.cycles.use_bump_map_correction = False",
        "    nodes = material.node_tree.nodes",
        "    node = next(n for n in nodes if n.type == 'BSDF_PRINCIPLED')",
        "    node.distribution = 'GGX'",
        "    for key, value in INPUTS.items():",
        "        node.inputs[key].default_value = value",
        "    return material",
        "",
        "",
        'if __name__ == "__main__":',
        "    material = build_material()",
        "    target = bpy.context.active_object",
        "    if target is not None and target.type == 'MESH':",
        "        target.data.materials.clear()",
        "        target.data.materials.append(material)",
        "    print(material.name)",
    ]
    return "\n".join(lines) + "\n", written, notes, deviation
