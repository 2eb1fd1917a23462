"""brdffit.export.materialx: MaterialX (the `materialx` package, in the test extra) reads every document written,
validates it against its standard libraries, and its GLSL and OSL shader generators produce code for each of its
three materials; the values are those of the fit under each node's names."""

from pathlib import Path

import numpy as np
import pytest

from brdffit import models
from brdffit.cli import EXIT_OK, main
from brdffit.export import ExportError, export, export_details
from brdffit.export.materialx import OPENPBR_NAMES, STANDARD_SURFACE_NAMES
from clients import materialx_document

mx = pytest.importorskip("MaterialX", reason="MaterialX (PyPI package materialx, test extra) is not installed")

SYNTHETIC = Path(__file__).resolve().parents[1] / "data" / "synthetic"
GLTF = dict(base_color=[0.7, 0.4, 0.15], metallic=0.2, roughness=0.4, specular=0.8, ior=1.6, clearcoat=0.5,
            clearcoat_roughness=0.2)
SHEENED = dict(GLTF, sheen_color=[0.8, 0.5, 0.4], sheen_roughness=0.37)


_document = materialx_document.load


def _inputs(doc, node: str) -> dict:
    shader = doc.getChild(node)
    return {i.getName(): i.getValue() for i in shader.getInputs()}


@pytest.fixture(scope="module", params=[GLTF, SHEENED], ids=["clearcoat", "clearcoat and sheen"])
def params(request):
    return request.param


@pytest.fixture(scope="module")
def text(params):
    return export(models.get("gltf", **params), "materialx", name="brdffit material")


def test_document_validates_against_the_standard_libraries(text):
    doc = _document(text)
    valid, message = doc.validate()
    assert valid, message
    materials = [m.getName() for m in doc.getMaterialNodes()]
    assert materials == ["brdffit_material", "brdffit_material_openpbr", "brdffit_material_standard"]
    assert doc.getChild("SR_brdffit_material").getNodeDef().getName() == "ND_gltf_pbr_surfaceshader"
    assert doc.getChild("SR_brdffit_material_openpbr").getNodeDef().getName() == "ND_open_pbr_surface_surfaceshader"
    assert doc.getChild("SR_brdffit_material_standard").getNodeDef().getName() == "ND_standard_surface_surfaceshader"


def _value(value):
    return np.asarray(value.asTuple() if hasattr(value, "asTuple") else value)


def test_values_are_the_fits_under_each_nodes_names(text, params):
    doc = _document(text)
    gltf_inputs, openpbr_inputs = _inputs(doc, "SR_brdffit_material"), _inputs(doc, "SR_brdffit_material_openpbr")
    standard_inputs = _inputs(doc, "SR_brdffit_material_standard")
    expected = {"sheen_color": [0.0, 0.0, 0.0], "sheen_roughness": 0.5, **params, "specular_color": [1.0, 1.0, 1.0]}
    for name, value in expected.items():
        np.testing.assert_allclose(_value(gltf_inputs[name]), value, rtol=1e-7)
        if name in OPENPBR_NAMES:
            np.testing.assert_allclose(_value(openpbr_inputs[OPENPBR_NAMES[name]]), value, rtol=1e-7)
        if name in STANDARD_SURFACE_NAMES:
            np.testing.assert_allclose(_value(standard_inputs[STANDARD_SURFACE_NAMES[name]]), value, rtol=1e-7)
    # Standard Surface's base weight and a white coat colour: MaterialX's translation graph to gltf_pbr then gives
    # base_color and the clearcoat weight back unchanged.
    assert _value(standard_inputs["base"]) == 1.0
    np.testing.assert_allclose(_value(standard_inputs["coat_color"]), [1.0, 1.0, 1.0])
    # A sheen is OpenPBR's fuzz: its weight the colour's largest channel, its colour the rest.
    if "sheen_color" in params:
        np.testing.assert_allclose(_value(openpbr_inputs["fuzz_weight"]), 0.8, rtol=1e-7)
        np.testing.assert_allclose(_value(openpbr_inputs["fuzz_color"]), [1.0, 0.625, 0.5], rtol=1e-7)
        np.testing.assert_allclose(_value(openpbr_inputs["fuzz_roughness"]), 0.37, rtol=1e-7)
        # Standard Surface's sheen: the same split, its roughness squared (the graph takes the square root).
        np.testing.assert_allclose(_value(standard_inputs["sheen"]), 0.8, rtol=1e-7)
        np.testing.assert_allclose(_value(standard_inputs["sheen_color"]), [1.0, 0.625, 0.5], rtol=1e-7)
        np.testing.assert_allclose(_value(standard_inputs["sheen_roughness"]), 0.37 ** 2, rtol=1e-7)
    else:
        assert "fuzz_weight" not in openpbr_inputs and "sheen" not in standard_inputs


@pytest.mark.parametrize("generator", ["glsl", "osl"])
def test_shader_generators_produce_code(text, generator):
    from MaterialX import PyMaterialXGenGlsl as genglsl
    from MaterialX import PyMaterialXGenOsl as genosl
    from MaterialX import PyMaterialXGenShader as genshader

    doc = _document(text)
    gen = (genglsl.GlslShaderGenerator if generator == "glsl" else genosl.OslShaderGenerator).create()
    context = genshader.GenContext(gen)
    context.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
    elements = genshader.findRenderableElements(doc)
    assert len(elements) == 3
    for element in elements:
        shader = gen.generate(element.getNamePath(), element, context)
        code = shader.getSourceCode(genshader.PIXEL_STAGE)
        assert len(code) > 1000 and ("void main" in code or "shader " in code), element.getNamePath()


def test_approximation_and_refusal_are_stated(text, params):
    assert "<!-- approximation: brdffit_material_openpbr (open_pbr_surface)" in text
    assert "<!-- approximation: brdffit_material_standard (standard_surface)" in text
    sheen_note = "<!-- approximation: brdffit_material (gltf_pbr): MaterialX's sheen_bsdf (conty_kulla)"
    assert (sheen_note in text) == ("sheen_color" in params)
    assert not export_details(models.get("gltf", **GLTF), "materialx").exact  # the OpenPBR material is approximate
    with pytest.raises(ExportError, match="--for gltf"):
        export(models.get("lambert+ggx"), "materialx")


def test_cli_exports_a_gltf_fit_to_materialx(tmp_path):
    """A fit of the gltf model (what `--for materialx` fits; tests/test_fit_for_target.py runs that selection)."""
    out = tmp_path / "fit"
    assert main(["fit", str(SYNTHETIC / "plastic.h5"), "--model", "gltf", "--quiet", "--no-report", "--out",
                 str(out)]) == EXIT_OK
    target = tmp_path / "plastic.mtlx"
    assert main(["export", str(out / "result.h5"), "--to", "materialx", "--quiet", "--out", str(target)]) == EXIT_OK
    valid, message = _document(target.read_text()).validate()
    assert valid, message
