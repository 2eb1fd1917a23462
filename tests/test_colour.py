"""brdffit.colour: spectra to CIE 1931 XYZ under D65 and linear sRGB against published values and colour-science,
a spectral model's exact RGB model against converting its values, exports of spectral fits read by Mitsuba 3, and
the command line on an ASTM E1392 fixture."""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from brdffit import colour, models
from brdffit.cli import EXIT_OK, main
from brdffit.export import ExportError, export, export_details
from brdffit.measurements import Measurements

DATA = Path(__file__).resolve().parent / "data" / "astm"
BANDS = np.arange(400.0, 701.0, 10.0)


def smooth_spectra():
    """Three reflectances at BANDS: a blue bump, a red step, a wavy grey (all in [0.1, 0.9])."""
    return [0.2 + 0.5 * np.exp(-((BANDS - 470.0) / 60.0) ** 2), 0.1 + 0.8 / (1.0 + np.exp(-(BANDS - 600.0) / 20.0)),
            0.5 + 0.3 * np.sin(BANDS / 40.0)]


def random_pairs(n=64, seed=1):
    rng = np.random.default_rng(seed)

    def draw():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    return draw(), draw()


# ----------------------------------------------------------------------------------------- published values
def test_d65_white_point_from_a_flat_unit_reflectance():
    # CIE 015:2018 Table 5 / ASTM E308: D65, 2° observer, (x, y) = (0.31271, 0.32902), XYZ = (95.047, 100, 108.883)/100.
    for bands in (np.arange(360.0, 831.0), BANDS, np.array([380.0, 455.5, 530.0, 781.0])):
        xyz = colour.spectral_colour(bands).xyz(np.ones(len(bands)))
        np.testing.assert_allclose(xyz, [0.95047, 1.0, 1.08883], atol=1e-4)
        np.testing.assert_allclose(colour.xyz_to_xy(xyz), [0.31271, 0.32902], atol=1e-4)
    np.testing.assert_allclose(colour.white_xyz(), [0.95047, 1.0, 1.08883], atol=1e-4)


def test_srgb_primaries_white_and_matrix():
    # IEC 61966-2-1: R (0.64, 0.33), G (0.30, 0.60), B (0.15, 0.06); white D65; luminance row 0.2126, 0.7152, 0.0722.
    for rgb, xy in zip(np.eye(3), colour.SRGB_PRIMARIES):
        np.testing.assert_allclose(colour.xyz_to_xy(colour.linear_srgb_to_xyz(rgb)), xy, atol=1e-12)
    np.testing.assert_allclose(colour.linear_srgb_to_xyz([1.0, 1.0, 1.0]), colour.white_xyz(), atol=1e-14)
    np.testing.assert_allclose(colour.xyz_to_xy(colour.white_xyz()), colour.SRGB_WHITE_XY, atol=1e-4)
    np.testing.assert_allclose(colour.LINEAR_SRGB_TO_XYZ[1], [0.2126, 0.7152, 0.0722], atol=1e-4)
    iec = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
    assert np.max(np.abs(colour.XYZ_TO_LINEAR_SRGB - iec)) < 4e-4  # the module doc's 3.7e-4
    np.testing.assert_allclose(colour.XYZ_TO_LINEAR_SRGB @ colour.LINEAR_SRGB_TO_XYZ, np.eye(3), atol=1e-14)


def test_flat_unit_reflectance_is_linear_srgb_white_at_any_bands():
    for bands in (BANDS, [400.0, 500.0, 600.0], [650.0, 420.0, 515.0, 580.0], [550.0]):
        conversion = colour.spectral_colour(bands)
        np.testing.assert_allclose(conversion.linear_srgb(np.ones(len(bands))), [1.0, 1.0, 1.0], atol=1e-12)
        np.testing.assert_allclose(conversion.rgb_weights.sum(axis=1), 1.0, atol=1e-12)


def test_srgb_transfer_function():
    # IEC 61966-2-1 Eq. 5: the break at L = 0.0031308 (V = 0.04045), V(1) = 1, V(0.5) = 1.055·0.5^(1/2.4) − 0.055.
    np.testing.assert_allclose(colour.srgb_encode([0.0, 0.0031308, 0.5, 1.0, 2.0, -1.0]),
                               [0.0, 0.0404500, 0.7353569830524495, 1.0, 1.0, 0.0], atol=1e-6)


def test_bands_outside_the_tables_and_end_values_held():
    # Outside the bands' range the spectrum holds its end value: a spectrum with equal ends gives the same colour
    # as its extension by that value.
    conversion = colour.spectral_colour([450.0, 550.0, 650.0])
    wide = colour.spectral_colour([360.0, 450.0, 550.0, 650.0, 830.0])
    np.testing.assert_allclose(conversion.xyz([0.3, 0.6, 0.2]), wide.xyz([0.3, 0.3, 0.6, 0.2, 0.2]), atol=1e-14)
    assert 0.0 < conversion.outside < 0.2 and wide.outside == 0.0
    assert "held at the nearest band's value outside 450-650 nm" in conversion.describe()
    with pytest.raises(colour.ColourError, match="scan.astm: meta wavelengths_nm: every band .900-1000 nm. lies "
                                                 "outside the CIE tables' 360-830 nm"):
        colour.spectral_colour([900.0, 1000.0], "scan.astm: meta wavelengths_nm")
    with pytest.raises(colour.ColourError, match="the wavelength 500 nm is given twice"):
        colour.spectral_colour([400.0, 500.0, 500.0])
    with pytest.raises(colour.ColourError, match="wavelength 1 is nan; expected a positive number of nm"):
        colour.spectral_colour([400.0, float("nan")])
    with pytest.raises(colour.ColourError, match="x.h5: meta wavelengths_nm must list one wavelength .nm. per "
                                                 "channel .3."):
        colour.wavelengths_of({"wavelengths_nm": [400.0, 500.0]}, 3, "x.h5")
    assert colour.wavelengths_of({}, 3) is None


# ------------------------------------------------------------------------------------------- colour-science
@pytest.fixture(scope="module")
def cs():
    return pytest.importorskip("colour", reason="colour-science (test extra) is not installed")


def test_tables_are_colour_sciences(cs):
    grid, cmfs, d65 = colour.tables()
    np.testing.assert_allclose(cmfs, cs.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"][grid], rtol=1e-10, atol=0)
    reference = cs.SDS_ILLUMINANTS["D65"]
    nodes = np.isin(grid, reference.wavelengths)  # its 5 nm values, 360-780 nm
    np.testing.assert_allclose(d65[nodes], reference[grid[nodes]], rtol=1e-10)


def test_non_flat_spectra_agree_with_colour_science(cs):
    grid, _, d65 = colour.tables()
    conversion = colour.spectral_colour(BANDS)
    cmfs = cs.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    illuminant = cs.SpectralDistribution(dict(zip(grid, d65)))
    warnings.simplefilter("ignore")  # colour-science says how it aligns and trims the spectra (this test only)
    for rho in smooth_spectra():
        ours = conversion.xyz(rho)
        # The same method: the spectrum linearly interpolated to 1 nm (held outside), summed with the same tables.
        same = cs.SpectralDistribution(dict(zip(grid, np.interp(grid, BANDS, rho))))
        np.testing.assert_allclose(ours, cs.sd_to_XYZ(same, cmfs, illuminant, method="Integration") / 100, atol=1e-10)
        # colour-science's default, ASTM E308's weights (Lagrange interpolation): the module doc's 1.4e-3.
        e308 = cs.sd_to_XYZ(cs.SpectralDistribution(dict(zip(BANDS, rho))), cmfs, cs.SDS_ILLUMINANTS["D65"]) / 100
        np.testing.assert_allclose(ours, e308, atol=2e-3)
        np.testing.assert_allclose(colour.xyz_to_linear_srgb(ours), cs.XYZ_to_RGB(ours, "sRGB"), atol=5e-4)


# ------------------------------------------------------------------------------------------------- models
SPECTRAL_MODELS = [
    ("lambert+ggx", dict(alpha=0.2, f0=0.04), ("rho_d", "ks")),
    ("lambert+cook-torrance(fresnel=dielectric)", dict(m=0.3, eta=1.6), ("rho_d", "ks")),
    ("gltf", dict(roughness=0.4, metallic=0.3), ("base_color",)),  # affine: a white specular offset
    ("ashikhmin-shirley", dict(n=40.0), ("rs",)),  # affine in rs
]


@pytest.mark.parametrize("spec, shape, amplitudes", SPECTRAL_MODELS, ids=[s for s, _, _ in SPECTRAL_MODELS])
def test_rgb_model_equals_the_spectral_model_converted_at_random_directions(spec, shape, amplitudes):
    spectra = smooth_spectra()
    values = {name: 0.6 * spectra[i % 3] for i, name in enumerate(amplitudes)}
    spectral = models.get(spec, channels=len(BANDS), **shape, **values)
    rgb, line = colour.rgb_model(spectral, BANDS)
    wi, wo = random_pairs()
    # The independent path: the spectral model's values at each direction pair, converted band by band.
    expected = colour.spectral_colour(BANDS).linear_srgb(np.asarray(models.evaluate_dirs(spectral, wi, wo)))
    np.testing.assert_allclose(np.asarray(models.evaluate_dirs(rgb, wi, wo)), expected, rtol=1e-10, atol=1e-12)
    assert rgb.channels == 3 and line.startswith("colour: 31 spectral bands (400-700 nm)") and "; exact:" in line


def test_rgb_model_refuses_a_per_band_parameter_that_is_not_an_amplitude():
    spec = "lambert+cook-torrance(fresnel=conductor)"
    same = models.get(spec, channels=len(BANDS), eta=np.full(len(BANDS), 0.2), k=np.full(len(BANDS), 3.0))
    assert "; exact:" in colour.rgb_model(same, BANDS)[1]  # the same value in every band: a shape parameter
    varying = same.replace(eta=np.linspace(0.2, 1.2, len(BANDS)))
    with pytest.raises(colour.ColourError, match="per-band parameter 'eta' .* is not an amplitude and varies between "
                                                 "the 31 bands .0.2 to 1.2."):
        colour.rgb_model(varying, BANDS)
    with pytest.raises(ExportError, match="mitsuba takes RGB colours, and the spectral fit has no exact RGB model"):
        export(varying, "mitsuba", wavelengths=BANDS)
    with pytest.raises(colour.ColourError, match="has 31 channels but 3 wavelengths"):
        colour.rgb_model(same, [400.0, 500.0, 600.0])


def test_out_of_gamut_amplitudes_are_set_to_zero_and_said():
    narrow = np.where(np.abs(BANDS - 520.0) < 15.0, 0.9, 0.0)  # a saturated green: negative linear R and B
    rgb, line = colour.rgb_model(models.get("lambert", channels=len(BANDS), rho_d=narrow), BANDS)
    assert np.all(np.asarray(rgb.params["rho_d"]) >= 0.0) and "approximate: outside the sRGB gamut" in line


def test_measurements_to_rgb():
    values = np.stack([smooth_spectra()[0], smooth_spectra()[2]])
    values[1, 5] = np.nan
    m = Measurements([0.1, 0.2], 0.0, [0.3, 0.4], np.pi, values, sigma=np.full(values.shape, 0.01),
                     channels=[f"{w:g}nm" for w in BANDS], meta={"wavelengths_nm": list(BANDS), "source": "x.astm"})
    rgb = colour.measurements_to_rgb(m)
    conversion = colour.spectral_colour(BANDS)
    assert rgb.channels == ("R", "G", "B") and "wavelengths_nm" not in rgb.meta
    np.testing.assert_allclose(rgb.values[0], conversion.linear_srgb(values[0]), atol=1e-15)
    assert np.all(np.isnan(rgb.values[1]))  # a band missing: no colour
    np.testing.assert_allclose(rgb.sigma[0], 0.01 * np.sqrt((conversion.rgb_weights ** 2).sum(axis=1)))
    assert rgb.meta["colour"].startswith("31 spectral bands")


# -------------------------------------------------------------------------------------------------- exports
def test_spectral_model_exports_to_mitsuba_as_its_rgb_model(mi):
    from brdffit.export.mitsuba import evaluate_in_mitsuba

    spectral = models.get("lambert+ggx(fresnel=dielectric)", channels=len(BANDS), rho_d=0.6 * smooth_spectra()[0],
                          ks=0.3 * smooth_spectra()[1], alpha=0.2, eta=1.5)
    with pytest.raises(ExportError, match="has 31 channels. A spectral fit is written as its sRGB equivalent when "
                                          "the wavelengths are given"):
        export(spectral, "mitsuba")
    details = export_details(spectral, "mitsuba", wavelengths=BANDS)
    assert "<!-- colour: 31 spectral bands (400-700 nm) converted to linear sRGB" in details.text
    assert details.exact
    wi, wo = random_pairs(seed=4)
    expected = colour.spectral_colour(BANDS).linear_srgb(np.asarray(models.evaluate_dirs(spectral, wi, wo)))
    np.testing.assert_allclose(evaluate_in_mitsuba(details.text, wi, wo), expected, rtol=1e-4, atol=1e-6)
    # JSON keeps the spectral model.
    assert json.loads(export(spectral, "json", wavelengths=BANDS))["channels"] == len(BANDS)


def test_spectral_gltf_model_exports_to_gltf_with_the_conversion_stated():
    spectral = models.get("gltf", channels=len(BANDS), base_color=0.8 * smooth_spectra()[1], roughness=0.5)
    document = json.loads(export(spectral, "gltf", wavelengths=BANDS))
    stated = json.dumps(document["asset"])
    assert "colour: 31 spectral bands" in stated and "exact" in stated
    base = document["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"]
    np.testing.assert_allclose(base[:3], colour.rgb_model(spectral, BANDS)[0].params["base_color"], rtol=1e-9)


# ---------------------------------------------------------------------------------------------- command line
def test_cli_fit_export_render_of_an_astm_file(tmp_path, mi, capsys):
    from brdffit.export.mitsuba import evaluate_in_mitsuba

    out = tmp_path / "fit"
    assert main(["fit", str(DATA / "cornell_like.astm"), "--model", "lambert", "--out", str(out), "--quiet"]) == EXIT_OK
    from brdffit.io.hdf5 import read_meta

    assert read_meta(out / "result.h5")["wavelengths_nm"] == [400.0, 500.0, 600.0]  # what export reads, alone
    xml = tmp_path / "m.xml"
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--out", str(xml), "--quiet"]) == EXIT_OK
    text = xml.read_text()
    assert "colour: 3 spectral bands (400-600 nm) converted to linear sRGB" in text
    assert "held at the nearest band's value outside 400-600 nm" in text
    assert main(["export", str(out / "result.h5"), "--to", "pbrt", "--out", str(tmp_path / "m.pbrt"),
                 "--quiet"]) == EXIT_OK
    # Mitsuba reads it, and what it evaluates is the sRGB of the fitted spectrum.
    from brdffit import FitResult

    spectral = FitResult.load(out / "result.h5").model
    wi, wo = random_pairs(8)
    expected = colour.spectral_colour([400.0, 500.0, 600.0]).linear_srgb(
        np.asarray(models.evaluate_dirs(spectral, wi, wo)))
    np.testing.assert_allclose(evaluate_in_mitsuba(text, wi, wo), expected, rtol=1e-4)
    # An export with the fit option is recorded for the report, which finds it for the spectral fit.
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--fit", "--out", str(tmp_path / "f.xml"),
                 "--quiet"]) == EXIT_OK
    assert main(["report", str(out / "result.h5"), "--quiet"]) == EXIT_OK
    assert "| mitsuba | --fit, " in (out / "report.md").read_text()
    for args in (["render", str(out / "result.h5")], ["render", str(DATA / "cornell_like.astm"), "--plane"]):
        png = tmp_path / f"{args[0]}{len(args)}.png"
        assert main(args + ["--out", str(png), "--resolution", "32", "--npy"]) == EXIT_OK
        assert "bands shown in sRGB" in capsys.readouterr().out
        assert np.load(png.with_suffix(".npy")).shape == (32, 32, 3)


def test_cli_render_of_bands_the_eye_does_not_see_is_grey(tmp_path, capsys):
    path = tmp_path / "infrared.astm"
    path.write_text("VARS theta_i,phi_i,theta_s,phi_s,900nm,1000nm\n0.0,0.0,0.2,3.1,0.20,0.25\n"
                    "0.5,0.0,0.5,3.1,0.22,0.27\n0.3,0.0,0.6,0.0,0.18,0.21\n0.7,0.0,0.3,3.1,0.21,0.26\n")
    png = tmp_path / "ir.png"
    assert main(["render", str(path), "--out", str(png), "--resolution", "16"]) == EXIT_OK
    assert "shown in grey as the mean of its bands" in capsys.readouterr().out and png.exists()
