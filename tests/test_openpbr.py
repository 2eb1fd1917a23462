"""The openpbr model (OpenPBR Surface as MaterialX 1.39 evaluates it) and its target: the MaterialX document that
`brdffit export --to openpbr` writes validates against MaterialX's own libraries (the `materialx` package, the test
extra) and its GLSL and OSL generators produce code for it; a fit for the target recovers a synthetic material and
exports exactly. The model itself is held to an independent transcription of MaterialX's GLSL at random directions
(tests/test_models.py, `reference_brdfs.openpbr`)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import brdffit
from brdffit import FitResult, models
from brdffit.cli import EXIT_OK, main
from brdffit.export import TARGETS, ExportError, export, export_details
from brdffit.export.openpbr import HELD
from brdffit.models.openpbr import ggx_albedo_fit
from brdffit.properties import directional_albedo, scan_albedo
from clients import materialx_document
from recovery import assert_recovered

SYNTHETIC = Path(__file__).resolve().parents[1] / "data" / "synthetic"
MATERIAL = dict(base_color=[0.7, 0.4, 0.15], base_metalness=0.25, base_diffuse_roughness=0.5,
                specular_roughness=0.45, specular_ior=1.7)


def _materialx():
    return pytest.importorskip("MaterialX", reason="MaterialX (PyPI package materialx, test extra) is not installed")


def _document(text: str):
    _materialx()
    return materialx_document.load(text)


def test_materialx_albedo_fit_is_the_ggx_albedo():
    """The rational fit the model reads (MaterialX's mx_ggx_dir_albedo_analytic, its 36 coefficients written again
    here) against brdffit's quadrature of GGX with height-correlated masking and F = 1: within MaterialX's own fit
    error, 0.03 (measured at most 0.027, at α = 0.1 and cosθ = 0.2); a wrong coefficient moves it by far more."""
    for alpha in (0.1, 0.3, 0.6, 1.0):
        lobe = models.get("ggx(shadowing=smith-correlated, fresnel=schlick)", ks=1.0, alpha=alpha, f0=1.0,
                          channels=1)
        mu = np.array([0.2, 0.5, 0.9])
        quadrature = np.asarray(directional_albedo(lobe, np.arccos(mu))).ravel()
        a, b = ggx_albedo_fit(mu, alpha, xp=np)
        np.testing.assert_allclose(a + b, quadrature, atol=0.03, err_msg=f"alpha {alpha}")


def _light_integral(model, theta_o):
    """∫ f_r(ωi, ωo) cosθi dωi at each viewing angle (ωo at φ = 0) by a product rule: Gauss-Legendre in cosθi,
    midpoints in φi (256 × 512 nodes)."""
    x, w = np.polynomial.legendre.leggauss(256)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(512) + 0.5) * 2 * np.pi / 512
    ti, pi_ = np.meshgrid(np.arccos(mu), phi, indexing="ij")
    weight = np.broadcast_to((wmu * mu)[:, None] * (2 * np.pi / 512), ti.shape).ravel()
    return np.stack([np.einsum("n,nc->c", weight, np.asarray(brdffit.evaluate(
        model, ti.ravel(), pi_.ravel(), np.full(ti.size, to), np.zeros(ti.size)))) for to in theta_o])


def test_view_albedo_of_a_layered_model_is_the_light_integral():
    """`scan_albedo(view=True)` at a viewing direction is ∫ f_r(ωi, ωo) cosθi dωi, here by a plain product rule
    over the light's hemisphere (Gauss-Legendre in cosθi, 256 × 512 nodes); openpbr's layering keeps it at or
    below 1 for a bright plastic where the albedo at grazing light passes 1."""
    model = models.get("openpbr", base_color=[0.9, 0.9, 0.9], specular_roughness=0.5, specular_ior=1.5,
                       channels=3)
    theta_o = np.radians([10.0, 60.0, 85.0])
    view = scan_albedo(model, theta_o, np.zeros(1), view=True)[:, 0, :]
    for k, (to, integral) in enumerate(zip(theta_o, _light_integral(model, theta_o))):
        np.testing.assert_allclose(view[k], integral, rtol=3e-3, err_msg=f"theta_o {np.degrees(to)}")
    assert view.max() <= 1.0
    assert scan_albedo(model).max() > 1.05  # grazing light: the layer's weight is the view's, not the light's


def test_a_lambert_plus_ggx_fit_is_judged_by_the_same_albedo_either_way():
    model = models.get("lambert+ggx", rho_d=[0.5, 0.3, 0.2], ks=[0.3] * 3, alpha=0.2)
    np.testing.assert_allclose(scan_albedo(model, view=True), scan_albedo(model), rtol=1e-12)


def test_fit_recovers_a_synthetic_openpbr_material():
    assert_recovered("openpbr", MATERIAL, noise=0.01, seed=5)


def test_export_is_exact_and_validates_in_materialx():
    _materialx()
    model = models.get("openpbr", **MATERIAL)
    details = export_details(model, "openpbr", name="brdffit material")
    assert details.exact and details.deviation.rms < 1e-12
    doc = _document(details.text)
    valid, message = doc.validate()
    assert valid, message
    shader = doc.getChild("SR_brdffit_material")
    assert shader.getNodeDef().getName() == "ND_open_pbr_surface_surfaceshader"
    inputs = {i.getName(): i.getValue() for i in shader.getInputs()}
    for name, value in dict(model.layout.local_params(model.params, 0), **HELD).items():
        got = inputs[name].asTuple() if hasattr(inputs[name], "asTuple") else inputs[name]
        np.testing.assert_allclose(np.asarray(got, dtype=float), np.asarray(value, dtype=float), rtol=1e-7,
                                   err_msg=name)
    assert [m.getName() for m in doc.getMaterialNodes()] == ["brdffit_material"]


@pytest.mark.parametrize("generator", ["glsl", "osl"])
def test_shader_generators_produce_code(generator):
    mx = _materialx()
    from MaterialX import PyMaterialXGenGlsl as genglsl
    from MaterialX import PyMaterialXGenOsl as genosl
    from MaterialX import PyMaterialXGenShader as genshader

    doc = _document(export(models.get("openpbr", **MATERIAL), "openpbr"))
    gen = (genglsl.GlslShaderGenerator if generator == "glsl" else genosl.OslShaderGenerator).create()
    context = genshader.GenContext(gen)
    context.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
    (element,) = genshader.findRenderableElements(doc)
    code = gen.generate(element.getNamePath(), element, context).getSourceCode(genshader.PIXEL_STAGE)
    assert "open_pbr" in code.lower() and ("void main" in code or "shader " in code)


def test_other_models_are_refused_or_fitted(monkeypatch):
    """Refused without the fit option; with it, the target's forms are fitted and the closest written (two forms
    here, to keep the test short; tests/test_export_blender.py fits Blender's two)."""
    monkeypatch.setitem(TARGETS, "openpbr", dataclasses.replace(TARGETS["openpbr"],
                                                                renders=("openpbr", "openpbr(fuzz=true)")))
    source = models.get("lambert+ggx", rho_d=[0.5, 0.3, 0.2], ks=[0.3] * 3, alpha=0.2)
    with pytest.raises(ExportError, match="--for openpbr"):
        export(source, "openpbr")
    details = export_details(source, "openpbr", fit=True)
    assert details.mapped.spec in ("openpbr", "openpbr(fuzz=True)") and not details.exact
    assert "<!-- measured deviation from the source model: " in details.text


def test_fit_for_openpbr_then_export(tmp_path, monkeypatch):
    """The artist's path on the README's plastic: `brdffit fit --for openpbr`, then `brdffit export --to openpbr`.
    The default candidates are cut to Lambert, as tests/test_export_blender.py does, and the target's forms to the
    plain and the coated one (the fuzz adds nothing on a plastic): the model written is the target's own fitted to
    all the data, the coated form (BIC 4,824 below the plain one: its coat and the roughened base are two GGX lobes,
    which follow the plastic's Schlick Fresnel term better than one). The plain model finds the plastic's
    dielectric: Schlick f0 = 0.04 is an index of 1.5 (1.509 measured)."""
    import importlib
    import importlib.util

    monkeypatch.setattr(importlib.import_module("brdffit.select"), "DEFAULT_CANDIDATES", ("lambert",))
    monkeypatch.setitem(TARGETS, "openpbr", dataclasses.replace(TARGETS["openpbr"],
                                                                renders=("openpbr", "openpbr(coat=true)")))
    out = tmp_path / "fit"
    assert main(["fit", str(SYNTHETIC / "plastic.h5"), "--for", "openpbr", "--quiet", "--no-report", "--out",
                 str(out)]) == EXIT_OK
    fitted = FitResult.load(out / "result.h5").model
    assert fitted.spec == models.get("openpbr(coat=true)").spec
    plain = brdffit.fit(brdffit.io.load(SYNTHETIC / "plastic.h5"), "openpbr")
    np.testing.assert_allclose(float(plain.params["specular_ior"]), 1.5, atol=0.03)
    target = tmp_path / "plastic.mtlx"
    assert main(["export", str(out / "result.h5"), "--to", "openpbr", "--quiet", "--out", str(target)]) == EXIT_OK
    text = target.read_text()
    assert "<!-- exact: " in text and "<open_pbr_surface " in text
    if importlib.util.find_spec("MaterialX") is not None:
        valid, message = _document(text).validate()
        assert valid, message


def test_materialx_export_states_the_measured_deviation_of_its_openpbr_counterpart():
    """`--to materialx` writes the glTF values under OpenPBR's names beside the glTF material; brdffit's openpbr
    model (with its coat for a clearcoat, its fuzz for a sheen) reads that counterpart and its comment states its
    deviation from the source, the deviation of the model built here from the same values by OpenPBR's names (a
    wrong mapping would differ)."""
    from brdffit.export import terms as tm
    from brdffit.export.materialx import OPENPBR_NAMES

    values = dict(base_color=[0.7, 0.4, 0.15], metallic=0.2, roughness=0.4, specular=0.8, ior=1.6)
    source = models.get("gltf", **values)
    counterpart = models.get("openpbr", **{OPENPBR_NAMES[k]: v for k, v in values.items()})
    expected = tm.measure(source, counterpart, pairs=tm.deviation_pairs(tm.peaks(source, counterpart)))
    assert 0.01 < expected.rms < 0.5  # an approximation, and a measurable one
    text = export(source, "materialx")
    line = next(line for line in text.splitlines() if "material_openpbr (open_pbr_surface)" in line)
    assert f"measures its deviation from the source: cosine-weighted relative RMS error {expected.rms:.3g}," in line
    # A clearcoat is OpenPBR's coat (of KHR_materials_clearcoat's index 1.5): measured too.
    coated = models.get("gltf", **values, clearcoat=0.5, clearcoat_roughness=0.2)
    counterpart = models.get("openpbr(coat=true)", **{OPENPBR_NAMES[k]: v for k, v in values.items()},
                             coat_weight=0.5, coat_roughness=0.2, coat_ior=1.5)
    expected = tm.measure(coated, counterpart, pairs=tm.deviation_pairs(tm.peaks(coated, counterpart)))
    line = next(line for line in export(coated, "materialx").splitlines()
                if "material_openpbr (open_pbr_surface)" in line)
    assert f"measures its deviation from the source: cosine-weighted relative RMS error {expected.rms:.3g}," in line
    # A sheen is OpenPBR's fuzz (weight: the sheen colour's largest channel, colour: divided by it): measured too.
    sheen = dict(values, sheen_color=[0.6, 0.3, 0.45], sheen_roughness=0.4)
    source = models.get("gltf", **sheen)
    counterpart = models.get("openpbr(fuzz=true)", **{OPENPBR_NAMES[k]: v for k, v in values.items()},
                             fuzz_weight=0.6, fuzz_color=[1.0, 0.5, 0.75], fuzz_roughness=0.4)
    expected = tm.measure(source, counterpart, pairs=tm.deviation_pairs(tm.peaks(source, counterpart)))
    line = next(line for line in export(source, "materialx").splitlines()
                if "material_openpbr (open_pbr_surface)" in line)
    assert f"measures its deviation from the source: cosine-weighted relative RMS error {expected.rms:.3g}," in line


FUZZY = dict(base_color=[0.35, 0.12, 0.08], base_diffuse_roughness=0.3, specular_roughness=0.6, specular_ior=1.5,
             fuzz_weight=0.8, fuzz_color=[0.9, 0.55, 0.5], fuzz_roughness=0.4)


def test_fuzz_alone_reflects_its_fitted_albedo():
    """With a black base and no specular (specular_weight 0: the modulated index is 1, so F = 0), what is left is
    the fuzz: its view albedo ∫ f cosθi dωi must be fuzz_weight · fuzz_color · E_z(μo), E_z MaterialX's fit of
    Zeltner's albedo, which holds only if the LTC the lobe evaluates integrates to 1 over the hemisphere and the
    response E_z D_LTC is f cosθi (module doc of brdffit.models.openpbr). At normal, oblique and grazing views
    and three roughnesses, to the quadrature's accuracy (1e-3 relative; a missing cosine or a wrong frame is off by
    tens of percent)."""
    from brdffit.models.sheen import zeltner_sheen_fit

    theta_o = np.radians([0.0, 45.0, 80.0])
    for rough in (0.1, 0.4, 0.9):
        model = models.get("openpbr(fuzz=true)", base_color=[0.0] * 3, specular_weight=0.0, fuzz_weight=0.7,
                           fuzz_color=[1.0, 0.5, 0.25], fuzz_roughness=rough)
        albedo, _, _ = zeltner_sheen_fit(np.cos(theta_o), rough, xp=np)
        expected = 0.7 * albedo[:, None] * np.array([1.0, 0.5, 0.25])
        np.testing.assert_allclose(_light_integral(model, theta_o), expected, rtol=1e-3, err_msg=f"roughness {rough}")


def test_coat_and_fuzz_of_weight_zero_are_the_model_without_them():
    rng = np.random.default_rng(3)
    angles = (rng.uniform(0, 1.5, 200), rng.uniform(-3, 3, 200), rng.uniform(0, 1.5, 200), rng.uniform(-3, 3, 200))
    plain = np.asarray(brdffit.evaluate(models.get("openpbr", **MATERIAL), *angles))
    layered = models.get("openpbr(coat=true, fuzz=true)", **MATERIAL, coat_weight=0.0, coat_color=[0.3, 0.5, 0.9],
                         coat_roughness=0.2, coat_ior=2.2, fuzz_weight=0.0, fuzz_color=[0.2, 0.9, 0.4])
    np.testing.assert_allclose(np.asarray(brdffit.evaluate(layered, *angles)), plain, rtol=1e-15, atol=0.0)


def test_fit_recovers_a_synthetic_fuzzy_material():
    """A felt-like OpenPBR material with fuzz, 1 % noise: the fit with fuzz recovers it (5 %), and it predicts the
    data far better than the fit without fuzz."""
    data, result = assert_recovered("openpbr(fuzz=true)", FUZZY, noise=0.01, seed=6)
    assert brdffit.fit(data, "openpbr").cost > 10 * result.cost


# A lacquered red: a clear coat over a dielectric base whose index (2.4) lies above the coat's, so that the base's
# specular stays visible under it (module doc of brdffit.models.openpbr: below the coat's index the graph's fix of
# total internal reflection puts a kink in the base's index, where its specular vanishes).
COATED = dict(base_color=[0.55, 0.12, 0.08], base_diffuse_roughness=0.2, specular_roughness=0.6, specular_ior=2.4,
              coat_weight=0.8, coat_roughness=0.3, coat_ior=1.5)


def test_fit_recovers_a_synthetic_coated_material():
    """A lacquered red with 0.1 % noise, recovered (5 %, 0.02) at the optimum that a fit from the truth reaches.
    The base's specular shows only through the coat: at 1 % noise the optimum puts its index at 2.22 and its
    roughness at 0.576 (against 2.4 and 0.6), hence the lower noise."""
    assert_recovered("openpbr(coat=true)", COATED, noise=0.001, seed=7)


@pytest.mark.parametrize("spec, values", [("openpbr(fuzz=true)", FUZZY), ("openpbr(coat=true)", COATED),
                                          ("openpbr(coat=true, fuzz=true)", dict(FUZZY, **COATED))])
def test_layered_export_is_exact_and_validates_in_materialx(spec, values):
    mx = _materialx()
    from MaterialX import PyMaterialXGenGlsl as genglsl
    from MaterialX import PyMaterialXGenShader as genshader

    model = models.get(spec, **values)
    details = export_details(model, "openpbr", name="felt")
    assert details.exact and details.deviation.rms < 1e-12
    doc = _document(details.text)
    valid, message = doc.validate()
    assert valid, message
    inputs = {i.getName(): i.getValue() for i in doc.getChild("SR_felt").getInputs()}
    for name, value in model.layout.local_params(model.params, 0).items():
        got = inputs[name].asTuple() if hasattr(inputs[name], "asTuple") else inputs[name]
        np.testing.assert_allclose(np.asarray(got, dtype=float), np.asarray(value, dtype=float), rtol=1e-7,
                                   err_msg=name)
    gen = genglsl.GlslShaderGenerator.create()
    context = genshader.GenContext(gen)
    context.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
    (element,) = genshader.findRenderableElements(doc)
    assert "void main" in gen.generate(element.getNamePath(), element, context).getSourceCode(genshader.PIXEL_STAGE)
