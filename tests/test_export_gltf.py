"""brdffit.export.gltf: the glTF file of a fit, checked by the Khronos glTF-Validator (the real client, npm package
gltf-validator, which checks the file against the glTF 2.0 schema: required fields and every value's range), the
material it states against an independent NumPy re-derivation of the specification's BRDF, the sphere it carries,
refusals and the CLI."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import reference_brdfs as ref
from brdffit import FitResult, models
from brdffit.cli import EXIT_OK, main
from brdffit.export import ExportError, export, export_details
from brdffit.export.gltf import read_material, sphere_mesh
from brdffit.export.terms import random_pairs
from brdffit.geometry import vector_to_spherical

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "data" / "synthetic"
VALIDATOR = ROOT / "node_modules" / "gltf-validator"
GLTF = dict(base_color=[0.7, 0.4, 0.15], metallic=0.2, roughness=0.4, specular=0.8, ior=1.6)
COATED = dict(GLTF, clearcoat=0.5, clearcoat_roughness=0.2)
SHEENED = dict(GLTF, sheen_color=[0.8, 0.5, 0.3], sheen_roughness=0.37)
NO_SHEEN = dict(sheen_color=[0.0, 0.0, 0.0], sheen_roughness=0.0)  # what a reader takes without the extension


def _validate(path: Path) -> dict:
    """The glTF-Validator's report on ``path`` (skips where Node.js or the validator is absent)."""
    node = shutil.which("node")
    if node is None or not VALIDATOR.is_dir():
        pytest.skip("the Khronos glTF-Validator is not installed: `npm install` in the project root (package.json; "
                    ".ci/run does it) with Node.js on the PATH")
    run = subprocess.run([node, str(ROOT / "tests" / "clients" / "validate_gltf.cjs"), str(path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def _problems(report: dict) -> list:
    return [(m["code"], m.get("pointer"), m["message"]) for m in report["issues"]["messages"]]


@pytest.mark.parametrize("params, written_coat", [
    (GLTF, dict(clearcoat=0.0, clearcoat_roughness=0.0, **NO_SHEEN)),
    (COATED, NO_SHEEN),
    (SHEENED, dict(clearcoat=0.0, clearcoat_roughness=0.0))], ids=["uncoated", "clearcoat", "sheen"])
def test_gltf_model_exports_exactly_and_states_what_it_means(params, written_coat):
    """Without a coat or a sheen nothing of KHR_materials_clearcoat or KHR_materials_sheen is written (a reader
    takes their defaults, 0 and 0)."""
    model = models.get("gltf", **params)
    details = export_details(model, "gltf")
    assert details.exact and details.deviation.rms == 0.0
    written = read_material(details.text)
    assert written == {"clearcoat": 0.0, "clearcoat_roughness": 0.1, **params, "specular_color": [1.0, 1.0, 1.0],
                       **written_coat}
    # The file's values, evaluated by the NumPy re-derivation of Appendix B (not by brdffit), are the model's.
    wi, wo = random_pairs(500, seed=3)
    angles = (*vector_to_spherical(wi), *vector_to_spherical(wo))
    want = ref.gltf(*(np.asarray(a) for a in angles), **written)
    np.testing.assert_allclose(details.written(wi, wo), want, rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("params, extensions", [
    (GLTF, {"KHR_materials_ior", "KHR_materials_specular"}),
    (COATED, {"KHR_materials_ior", "KHR_materials_specular", "KHR_materials_clearcoat"}),
    (dict(SHEENED, clearcoat=0.5), {"KHR_materials_ior", "KHR_materials_specular", "KHR_materials_sheen",
                                    "KHR_materials_clearcoat"})],
    ids=["uncoated", "clearcoat", "sheen and clearcoat"])
def test_gltf_file_passes_the_khronos_validator(tmp_path, params, extensions):
    path = tmp_path / "material.gltf"
    path.write_text(export(models.get("gltf", **params), "gltf", name="brdffit material"))
    report = _validate(path)
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, _problems(report)
    assert report["info"]["materialCount"] == 1 and report["info"]["drawCallCount"] == 1
    assert set(report["info"]["extensionsUsed"]) == extensions


def test_validator_reports_a_value_out_of_range(tmp_path):
    """The validator is live: a metallicFactor of 1.5 and an ior of 0.5 are errors it names (what the exporter
    never writes, since the model's declared bounds are the file's ranges)."""
    document = json.loads(export(models.get("gltf", **GLTF), "gltf"))
    document["materials"][0]["pbrMetallicRoughness"]["metallicFactor"] = 1.5
    document["materials"][0]["extensions"]["KHR_materials_ior"]["ior"] = 0.5
    path = tmp_path / "bad.gltf"
    path.write_text(json.dumps(document))
    codes = {(code, pointer) for code, pointer, _ in _problems(_validate(path))}
    assert ("VALUE_NOT_IN_RANGE", "/materials/0/pbrMetallicRoughness/metallicFactor") in codes
    assert ("VALUE_NOT_IN_RANGE", "/materials/0/extensions/KHR_materials_ior/ior") in codes


def test_every_declared_bound_is_inside_the_files_range():
    specs = models.get("gltf").param_specs
    for name, (lower, upper) in {"base_color": (0, 1), "metallic": (0, 1), "roughness": (0, 1),
                                 "specular": (0, 1), "ior": (1, np.inf), "specular_color": (0, np.inf),
                                 "sheen_color": (0, 1), "sheen_roughness": (0, 1)}.items():
        assert lower <= specs[name].lower and specs[name].upper <= upper, name


def test_sphere_is_closed_outward_and_unit():
    positions, normals, indices = sphere_mesh()
    np.testing.assert_allclose(np.linalg.norm(positions, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(normals, positions, atol=1e-6)
    a, b, c = (positions[indices[k::3]].astype(float) for k in range(3))
    outward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c)
    assert np.all(outward > 0)  # counter-clockwise seen from outside: glTF's front faces
    # Area of the triangles against 4π (a closed sphere, no holes at the poles).
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    assert area == pytest.approx(4 * np.pi, rel=0.01)


def test_other_models_are_refused_or_fitted_with_their_deviation(tmp_path):
    source = models.get("lambert+ggx", rho_d=[0.5, 0.3, 0.2], ks=[0.3] * 3, alpha=0.2)
    with pytest.raises(ExportError, match="--for gltf"):
        export(source, "gltf")
    details = export_details(source, "gltf", fit=True)
    assert not details.exact and details.mapped.spec == "gltf"
    comments = json.loads(details.text)["asset"]["extras"]["brdffit"]["comments"]
    assert any(line.startswith("measured deviation from the source model: ") for line in comments)
    # A Lambert + GGX plastic is nearly a glTF dielectric (its Fresnel-weighted diffuse differs): the fit's
    # deviation is 0.051 here, and it stays well below the diffuse part alone's.
    assert details.deviation.rms < 0.08
    path = tmp_path / "fitted.gltf"
    path.write_text(details.text)
    report = _validate(path)
    assert report["issues"]["numErrors"] == 0, _problems(report)


def test_cli_exports_a_gltf_fit(tmp_path):
    out = tmp_path / "fit"
    assert main(["fit", str(SYNTHETIC / "plastic.h5"), "--model", "gltf", "--quiet", "--no-report", "--out",
                 str(out)]) == EXIT_OK
    target = tmp_path / "plastic.gltf"
    assert main(["export", str(out / "result.h5"), "--to", "gltf", "--quiet", "--out", str(target)]) == EXIT_OK
    written = read_material(target.read_text())
    fitted = FitResult.load(out / "result.h5").model.params
    np.testing.assert_allclose(written["base_color"], fitted["base_color"], rtol=1e-12)
    assert written["roughness"] == pytest.approx(float(fitted["roughness"]), rel=1e-12)
    report = _validate(target)
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, _problems(report)
