"""brdffit.export: JSON round trip, Mitsuba 3 <bsdf> and pbrt-v4 MakeNamedMaterial values, refusals."""

import json
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import brdffit
from brdffit.export import EXPORT_FORMATS, ExportError, export, f0_to_eta
from brdffit.models import get, model_from_dict


def _params(xml_text):
    root = ET.fromstring(xml_text)
    assert root.tag == "bsdf"
    return root, {child.get("name"): (child.tag, child.get("value")) for child in root}


def _floats(text):
    return [float(v) for v in re.split(r"[,\s]+", text.strip())]


def test_formats():
    assert EXPORT_FORMATS == ("json", "mitsuba", "pbrt")
    with pytest.raises(ValueError, match="unknown export format"):
        export(get("lambert"), to="blender")


def test_lambert_to_mitsuba_diffuse():
    text = export(get("lambert", rho_d=[0.5, 0.25, 0.125]), "mitsuba", name="paint")
    assert text.startswith("<!-- brdffit ")
    assert "lambert" in text.splitlines()[0] and brdffit.__version__ in text.splitlines()[0]
    root, params = _params(text)
    assert root.get("type") == "diffuse" and root.get("id") == "paint"
    assert params["reflectance"][0] == "rgb"
    assert _floats(params["reflectance"][1]) == [0.5, 0.25, 0.125]


def test_two_lambert_lobes_sum_and_single_channel_repeats():
    root, params = _params(export(get("lambert+lambert", channels=1, rho_d=0.2, rho_d_2=0.3), "mitsuba"))
    assert _floats(params["reflectance"][1]) == pytest.approx([0.5, 0.5, 0.5])


def test_ggx_conductor_to_mitsuba_roughconductor():
    model = get("ggx(fresnel=conductor)", alpha=0.12, ks=1.0, eta=[0.2, 0.4, 1.1], k=[3.9, 2.4, 2.2])
    root, params = _params(export(model, "mitsuba"))
    assert root.get("type") == "roughconductor"
    assert params["distribution"] == ("string", "ggx")
    assert params["alpha"] == ("float", "0.12")
    assert _floats(params["eta"][1]) == [0.2, 0.4, 1.1]
    assert _floats(params["k"][1]) == [3.9, 2.4, 2.2]
    assert _floats(params["specular_reflectance"][1]) == [1.0, 1.0, 1.0]


def test_beckmann_cook_torrance_conductor_keeps_distribution_and_notes_vcavity():
    text = export(get("cook-torrance(fresnel=conductor, material=gold)", m=0.3), "mitsuba")
    root, params = _params(text)
    assert params["distribution"] == ("string", "beckmann")
    assert float(params["alpha"][1]) == 0.3
    assert "V-cavity" in text and "<!-- approximation:" in text


def test_f0_to_eta_by_hand():
    # f0 = ((eta - 1)/(eta + 1))^2: eta = 1.5 gives (0.5/2.5)^2 = 0.04.
    assert f0_to_eta(0.04) == pytest.approx(1.5, rel=1e-12)
    assert f0_to_eta(0.0) == 1.0
    with pytest.raises(ExportError):
        f0_to_eta(1.0)


def test_lambert_schlick_to_mitsuba_roughplastic():
    model = get("lambert+ggx", rho_d=[0.6, 0.3, 0.1], ks=0.8, alpha=0.25, f0=0.04)
    text = export(model, "mitsuba")
    root, params = _params(text)
    assert root.get("type") == "roughplastic"
    assert params["distribution"] == ("string", "ggx")
    assert float(params["alpha"][1]) == 0.25
    assert float(params["int_ior"][1]) == pytest.approx(1.5, abs=1e-9)
    assert float(params["ext_ior"][1]) == 1.0
    assert _floats(params["diffuse_reflectance"][1]) == [0.6, 0.3, 0.1]
    assert _floats(params["specular_reflectance"][1]) == [0.8, 0.8, 0.8]
    assert "Schlick" in text and "roughplastic's diffuse term" in text


def test_dielectric_specular_alone_has_black_diffuse():
    root, params = _params(export(get("cook-torrance(fresnel=dielectric, material=diamond)"), "mitsuba"))
    assert float(params["int_ior"][1]) == pytest.approx(2.42)
    assert _floats(params["diffuse_reflectance"][1]) == [0.0, 0.0, 0.0]


def test_pbrt_diffuse_conductor_and_coateddiffuse():
    text = export(get("lambert", rho_d=[0.5, 0.25, 0.125]), "pbrt", name="paint")
    assert text.startswith("# brdffit ")
    assert re.search(r'MakeNamedMaterial "paint"\s+"string type" \[ "diffuse" \]\s+'
                     r'"rgb reflectance" \[ 0\.5 0\.25 0\.125 \]', text)

    text = export(get("ggx(fresnel=conductor)", alpha=0.12, ks=1.0, eta=[0.2, 0.4, 1.1], k=[3.9, 2.4, 2.2]), "pbrt")
    assert re.search(r'"string type" \[ "conductor" \]', text)
    assert re.search(r'"rgb eta" \[ 0\.2 0\.4 1\.1 \]', text)
    assert re.search(r'"rgb k" \[ 3\.9 2\.4 2\.2 \]', text)
    assert re.search(r'"float roughness" \[ 0\.12 \]', text)
    assert re.search(r'"bool remaproughness" \[ false \]', text)
    assert "dropped" not in text  # ks = 1: nothing lost

    text = export(get("lambert+ggx", rho_d=0.4, ks=0.5, alpha=0.3, f0=0.04), "pbrt")
    assert re.search(r'"string type" \[ "coateddiffuse" \]', text)
    assert re.search(r'"rgb reflectance" \[ 0\.4 0\.4 0\.4 \]', text)
    assert re.search(r'"float roughness" \[ 0\.3 \]', text)
    assert float(re.search(r'"float eta" \[ ([0-9.eE+-]+) \]', text).group(1)) == pytest.approx(1.5, abs=1e-9)
    assert "ks = 0.5, 0.5, 0.5 was dropped" in text


def test_pbrt_beckmann_is_flagged_approximate():
    text = export(get("cook-torrance(fresnel=conductor)", m=0.2), "pbrt")
    assert "Trowbridge-Reitz" in text
    assert re.search(r'"float roughness" \[ 0\.2 \]', text)


def test_json_round_trips():
    model = get("lambert+cook-torrance(distribution=ggx, fresnel=conductor, material=copper)", rho_d=[0.1, 0.2, 0.3])
    d = json.loads(export(model, "json"))
    assert "brdffit" in d["comment"] and d["spec"] == model.spec
    back = model_from_dict(d)
    assert back.spec == model.spec and back.channels == model.channels
    for name, value in model.params.items():
        np.testing.assert_array_equal(np.asarray(back.params[name]), np.asarray(value))


@pytest.mark.parametrize("spec", ["oren-nayar", "lambert+ward", "phong", "blinn-phong", "ashikhmin-shirley",
                                  "lafortune", "toon-diffuse", "lambert+toon-specular"])
def test_unsupported_lobes_raise_naming_the_lobe(spec):
    lobe = spec.split("+")[-1]
    for to in ("mitsuba", "pbrt"):
        with pytest.raises(ExportError, match=f"lobe '{lobe}'.*exportable: lambert"):
            export(get(spec), to)
    assert json.loads(export(get(spec), "json"))["spec"] == spec  # json takes every model


def test_unsupported_combinations_raise():
    with pytest.raises(ExportError, match="conductor summed with a lambert"):
        export(get("lambert+ggx(fresnel=conductor)"), "mitsuba")
    with pytest.raises(ExportError, match="2 microfacet lobes"):
        export(get("ggx+ggx"), "pbrt")
    with pytest.raises(ExportError, match="5 channels"):
        export(get("lambert", channels=5), "mitsuba")


def test_fit_result_exports():
    truth = get("lambert+ggx", rho_d=[0.4, 0.3, 0.2], ks=0.6, alpha=0.2, f0=0.04)
    data = brdffit.synth.generate(truth, "uniform", n=300, seed=1)
    result = brdffit.fit(data, "lambert+ggx", fixed={"f0": 0.04})
    d = json.loads(export(result, "json"))
    assert set(d["stderr"]) == set(d["params"]) and d["status"] == result.status
    assert model_from_dict(d).spec == "lambert+ggx"
    root, params = _params(export(result, "mitsuba"))
    assert root.get("type") == "roughplastic"
    assert float(params["alpha"][1]) == pytest.approx(0.2, rel=1e-3)
    assert _floats(params["diffuse_reflectance"][1]) == pytest.approx([0.4, 0.3, 0.2], rel=1e-3)
    assert "coateddiffuse" in export(result, "pbrt")
