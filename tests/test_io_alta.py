"""ALTA text data: the CEA retro-reflection file, each parameterisation against closed forms, round trips, errors."""

import math
from pathlib import Path

import numpy as np
import pytest

import brdffit.io as bio
from brdffit.io import FormatError, read_alta, write_alta
from brdffit.io.alta import PARAM_IN, looks_like_alta
from brdffit.measurements import MeasurementError, Measurements

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CEA = SHARED / "alta-cea-retro" / "retro-gray-tape.dat"
DEG = math.pi / 180


def cea_file() -> Path:
    if not CEA.exists():
        pytest.skip(f"{CEA} not found: real-data tests need ../shared beside the project")
    return CEA


@pytest.fixture(scope="module")
def cea():
    return read_alta(cea_file())


def write(tmp_path, text, name="x.alta"):
    path = tmp_path / name
    path.write_text(text)
    return path


def unit(theta, phi):
    """ω = (sinθ cosφ, sinθ sinφ, cosθ) (docs/conventions.md), in NumPy."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def random_pairs(rng, n=40):
    """Direction pairs well above the horizon, arbitrary azimuths."""
    return (rng.uniform(0.1, 1.4, n), rng.uniform(0, 2 * math.pi, n), rng.uniform(0.1, 1.4, n),
            rng.uniform(0, 2 * math.pi, n))


def fmt(rows):
    return "\n".join(" ".join(repr(float(v)) for v in row) for row in rows) + "\n"


# ------------------------------------------------------------------------------------------- the CEA real file
def test_cea_file_counts_header_and_values(cea):
    raw = np.loadtxt(CEA, comments="#")  # the file's numbers, as NumPy reads them
    assert cea.n == 7405 == len(raw) and cea.channels == ("c0",)
    np.testing.assert_array_equal(cea.values[:, 0], raw[:, 3])
    np.testing.assert_array_equal(cea.theta_i, raw[:, 0])
    np.testing.assert_array_equal(cea.phi_i, 0.0)
    np.testing.assert_allclose(cea.theta_o, np.minimum(np.hypot(raw[:, 1], raw[:, 2]), math.pi / 2), atol=1e-15)
    levels, counts = np.unique(np.round(np.degrees(cea.theta_i), 9), return_counts=True)
    assert levels.tolist() == [15, 30, 60] and counts.tolist() == [2645, 2665, 2095]
    assert cea.meta["format"] == "alta"
    alta = cea.meta["alta"]
    assert alta["param_in"] == "ISOTROPIC_TL_TV_PROJ_DPHI" and alta["param_out"] == "INV_STERADIAN"
    assert alta["dim"] == [3, 1] and alta["vs"] == 0
    assert alta["header"]["URL"] == "https://hal.archives-ouvertes.fr/hal-01083366/"
    assert alta["header"]["SAMPLE"] == '"Gray Tape"'
    read = cea.meta["read"]
    assert read["rows"] == 7405 and read["incidences"] == 3
    assert "no #PARAM_OUT" in read["values"] and read["azimuth"].startswith("φi = 0")
    assert cea.sigma is None


def test_cea_peaks_sit_at_the_retro_direction(cea):
    """ALTA puts L at φ = 0 and V at atan2(x₂, x₁): the retro peak (ωo = ωi) is then where the data peaks.

    With the opposite reading (L at φ = π) the 15° and 30° peaks would fall on the mirror direction instead.
    """
    wi, wo, f = cea.wi(), cea.wo(), cea.values[:, 0]
    mirror = wi * np.array([-1.0, -1.0, 1.0])

    def within(a, b, degrees):
        return np.einsum("ij,ij->i", a, b) > math.cos(math.radians(degrees))

    for theta, ratio in ((15, 94), (30, 50)):
        rows = np.isclose(cea.theta_i, theta * DEG)
        k = np.flatnonzero(rows)[np.argmax(f[rows])]
        assert np.degrees(np.arccos(min(1.0, wo[k] @ wi[k]))) < 1e-6  # the maximum: exactly ωo = ωi
        retro, specular = f[rows & within(wo, wi, 2)].max(), f[rows & within(wo, mirror, 2)].max()
        assert retro / specular > ratio  # 72.5 / 0.769 and 42.5 / 0.843
    # At 60° a specular lobe (1.43 at 1.0° from the mirror direction) edges out the retro peak (1.31).
    rows = np.isclose(cea.theta_i, 60 * DEG)
    k = np.flatnonzero(rows)[np.argmax(f[rows])]
    assert np.degrees(np.arccos(wo[k] @ mirror[k])) == pytest.approx(1.0, abs=0.01)
    assert f[rows & within(wo, wi, 2)].max() == pytest.approx(1.3107, abs=1e-4)


def test_cea_round_trip_through_its_own_parameterisation(cea, tmp_path):
    path = tmp_path / "cea.alta"
    write_alta(cea, path, param_in="ISOTROPIC_TL_TV_PROJ_DPHI")
    text = path.read_text().splitlines()
    assert text[:7] == ['#SAMPLE "Gray Tape"', '#ORIGIN "retro-reflection BRDF measures from CEA"',
                        "#URL https://hal.archives-ouvertes.fr/hal-01083366/", "#DIM 3 1",
                        "#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI", "#PARAM_OUT INV_STERADIAN", "#VS 0"]
    raw = np.loadtxt(CEA, comments="#")
    written = np.loadtxt(path, comments="#")
    np.testing.assert_array_equal(written[:, [0, 3]], raw[:, [0, 3]])
    np.testing.assert_allclose(written[:, 1:3], raw[:, 1:3], rtol=0, atol=4e-15)  # a few ulps of atan2, cos
    back = read_alta(path)
    np.testing.assert_array_equal(back.values, cea.values)
    np.testing.assert_allclose(back.wo(), cea.wo(), rtol=0, atol=1e-14)
    assert back.meta["alta"]["header"] == cea.meta["alta"]["header"]


def test_detect_format_by_content_whatever_the_extension(tmp_path):
    cea_file()
    for name in ("gray.dat", "gray.txt", "gray"):
        (tmp_path / name).symlink_to(CEA)
        assert bio.detect_format(tmp_path / name) == "alta"
        assert bio.load(tmp_path / name).n == 7405
    table = write(tmp_path, "# measured 2026\n#operator: me\ntheta_i,phi_i,theta_o,phi_o,f\n0,0,10,180,0.3\n",
                  "plain.dat")
    assert bio.detect_format(table) == "table" and bio.load(table).meta["format"] == "table"
    assert looks_like_alta(b"\n\n#ALTA HEADER BEGIN\n#DIM 4 1\n") and not looks_like_alta(b"#DIMS 4\n1 2\n#DIM 4 1")
    assert not looks_like_alta(b"# DIM 4 1\n1 2 3 4 5\n")  # '# ' is a comment, not a header entry


# ---------------------------------------------------------------------------- parameterisations, closed forms
def test_spherical_is_read_as_it_is(tmp_path):
    rows = [[0.5, 0.25, 1.0, 3.5, 0.125], [0.0, 0.0, 1.5, 6.0, 2.0]]
    m = read_alta(write(tmp_path, "#DIM 4 1\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n#PARAM_OUT INV_STERADIAN\n" + fmt(rows)))
    np.testing.assert_array_equal(np.stack([m.theta_i, m.phi_i, m.theta_o, m.phi_o, m.values[:, 0]], 1), rows)
    assert m.meta["read"]["incidences"] == 2 and "values" not in m.meta["read"]


def test_cartesian_packs_the_view_vector_first(tmp_path, rng):
    theta_i, phi_i, theta_o, phi_o = random_pairs(rng)
    rows = np.concatenate([unit(theta_o, phi_o), unit(theta_i, phi_i), np.ones((len(theta_i), 1))], axis=1)
    rows = np.vstack([rows, [0, 0, 1, math.sin(DEG * 30), 0, math.cos(DEG * 30), 1]])  # V the normal, L at 30°
    m = read_alta(write(tmp_path, "#DIM 6 1\n#PARAM_IN CARTESIAN\n" + fmt(rows)))
    np.testing.assert_allclose(m.theta_i[:-1], theta_i, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.theta_o[:-1], theta_o, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.exp(1j * m.phi_i[:-1]), np.exp(1j * phi_i), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.exp(1j * m.phi_o[:-1]), np.exp(1j * phi_o), rtol=0, atol=1e-12)
    assert (m.theta_i[-1], m.phi_i[-1], m.theta_o[-1]) == pytest.approx((30 * DEG, 0.0, 0.0), abs=1e-15)


def test_isotropic_projected_dphi(tmp_path):
    theta_l = np.array([0.3, 0.6, 1.0, 0.2])
    theta_v = np.array([0.5, 0.0, 1.2, 1.5])
    dphi = np.array([0.7, 0.0, -2.5, math.pi])
    rows = np.stack([theta_l, theta_v * np.cos(dphi), theta_v * np.sin(dphi), [1, 2, 3, 4]], axis=1)
    m = read_alta(write(tmp_path, "#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n" + fmt(rows)))
    np.testing.assert_array_equal(m.theta_i, theta_l)
    np.testing.assert_array_equal(m.phi_i, 0.0)
    np.testing.assert_allclose(m.theta_o, theta_v, rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.phi_o, np.mod(dphi, 2 * math.pi), rtol=0, atol=1e-15)  # φo = Δφ = φv − φl


def rusinkiewicz_alta(theta_h, theta_d, phi_d):
    """(L, V) of ALTA's RUSIN_TH_TD_PD from the definition (Rusinkiewicz 1998, φh = 0) with explicit matrices.

    ALTA (params.h, half_to_cartesian): V = R_z(φh) R_y(θh) d(θd, φd), L = 2 (V·h) h − V.
    """
    h = unit(theta_h, 0.0)
    d = unit(theta_d, phi_d)
    c, s = np.cos(theta_h), np.sin(theta_h)
    zero, one = np.zeros_like(c), np.ones_like(c)
    r_y = np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1), np.stack([-s, zero, c], -1)], -2)
    v = np.einsum("nij,nj->ni", r_y, d)
    light = 2 * np.einsum("ni,ni->n", v, h)[:, None] * h - v
    return light, v


def test_rusinkiewicz_against_the_definition(tmp_path, rng):
    n = 30
    triples = np.stack([rng.uniform(0.05, 0.6, n), rng.uniform(0.05, 0.9, n), rng.uniform(-math.pi, math.pi, n)], 1)
    triples = np.vstack([triples, [0.4, 0.0, 0.0], [0.0, 0.5, 0.0]])
    rows = np.concatenate([triples, np.full((n + 2, 1), 0.5)], axis=1)
    m = read_alta(write(tmp_path, "#DIM 3 1\n#PARAM_IN RUSIN_TH_TD_PD\n#PARAM_OUT INV_STERADIAN\n" + fmt(rows)))
    light, view = rusinkiewicz_alta(*triples.T)
    np.testing.assert_allclose(m.wi(), light, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.wo(), view, rtol=0, atol=1e-12)
    # θd = 0: both directions are the half vector (θ = θh, φ = 0); θh = 0: V and L mirror images about the normal
    assert (m.theta_i[n], m.theta_o[n], m.phi_o[n]) == pytest.approx((0.4, 0.4, 0.0), abs=1e-12)
    np.testing.assert_allclose(m.wi()[n + 1], m.wo()[n + 1] * [-1, -1, 1], atol=1e-12)
    assert m.theta_o[n + 1] == pytest.approx(0.5, abs=1e-12) and m.meta["read"]["azimuth"].startswith("φh = 0")


# ALTA's own conversions, printed once (%.17g) by a small C++ program built on ALTA's sources/core/params.cpp
# (belcour/alta 7c54015) calling params::convert(row, <PARAM_IN>, CARTESIAN, out): out = (V, L).
ALTA_TO_CARTESIAN = {
    "ISOTROPIC_TL_TV_PROJ_DPHI": [
        ([0.3, 0.5 * math.cos(0.7), 0.5 * math.sin(0.7)],
         [0.36668487758608259, 0.308854411682284, 0.87758256189037276, 0.29552020666133955, 0, 0.95533648912560598]),
        ([1.0, 1.2 * math.cos(-2.5), 1.2 * math.sin(-2.5)],
         [-0.74669716316284307, -0.55779943016749778, 0.36235775447667362, 0.8414709848078965, 0,
          0.54030230586813977])],
    "RUSIN_TH_TD_PD": [
        ([0.3, 0.4, 0.5], [0.59867527225759953, 0.18669709850368066, 0.77893010713259503, -0.054291001666736727,
                           -0.18669709850368066, 0.98091624542991884]),
        ([0.2, 0.6, -2.0], [-0.066321465279982811, -0.51342794813459414, 0.85556601458766268, 0.39425921387085505,
                            0.51342794813459414, 0.76220168876238792]),
        ([0.5, 0.3, 2.0], [0.35008778365911286, 0.26871576349214971, 0.89734630003331561, 0.56593763803547115,
                           -0.26871576349214971, 0.77942698715509173])],
    "SPHERICAL_TL_PL_TV_PV": [
        ([0.5, 0.25, 1.0, 3.5], [-0.78800113088452672, -0.29517390805807697, 0.54030230586813977,
                                 0.46452135963892854, 0.11861177641841196, 0.87758256189037276])],
}
# ... and params::convert(cart, CARTESIAN, <PARAM_IN>, out) for V = (0.3, -0.2, √0.87), L = (-0.4, 0.1, √0.83).
ALTA_CARTESIAN = [0.3, -0.2, math.sqrt(1 - 0.13), -0.4, 0.1, math.sqrt(1 - 0.17)]
ALTA_FROM_CARTESIAN = {
    "ISOTROPIC_TL_TV_PROJ_DPHI": [0.42498878296240344, -0.34737373188215781, -0.12406204710077066],
    "RUSIN_TH_TD_PD": [0.076551920097724213, 0.39081611815865686, 1.9523151450660834],
    "SPHERICAL_TL_PL_TV_PV": [0.42498878296240344, 2.8966139904629289, 0.36886298422662456, -0.58800260354756761],
}


@pytest.mark.parametrize("param_in", list(ALTA_TO_CARTESIAN))
def test_directions_match_altas_own_conversion(tmp_path, param_in):
    rows = [x + [1.0] for x, _ in ALTA_TO_CARTESIAN[param_in]]
    m = read_alta(write(tmp_path, f"#DIM {len(rows[0]) - 1} 1\n#PARAM_IN {param_in}\n" + fmt(rows)))
    expected = np.array([cart for _, cart in ALTA_TO_CARTESIAN[param_in]])
    np.testing.assert_allclose(np.concatenate([m.wo(), m.wi()], axis=1), expected, rtol=0, atol=1e-14)
    # writing: the same numbers as ALTA's from_cartesian, except the sign of θv·sinΔφ, where ALTA's from_cartesian
    # takes φl − φv against its own to_cartesian's φv − φl (the reading above, which the tests pin)
    source = read_alta(write(tmp_path, "#DIM 6 1\n#PARAM_IN CARTESIAN\n" + fmt([ALTA_CARTESIAN + [1.0]]), "c.alta"))
    written = PARAM_IN[param_in].from_angles(source)[0]
    alta = np.array(ALTA_FROM_CARTESIAN[param_in])
    if param_in == "ISOTROPIC_TL_TV_PROJ_DPHI":
        alta[2] = -alta[2]
    np.testing.assert_allclose(np.exp(1j * written), np.exp(1j * alta), rtol=0, atol=1e-14)  # angles mod 2π


@pytest.mark.parametrize("param_in", list(PARAM_IN))
def test_round_trip_every_parameterisation(tmp_path, rng, param_in):
    theta_i, phi_i, theta_o, phi_o = random_pairs(rng)
    values = rng.uniform(0.01, 5.0, (len(theta_i), 3))
    m = Measurements(theta_i, phi_i, theta_o, phi_o, values, sigma=values * 0.05, channels=("R", "G", "B"))
    path = tmp_path / "rt.alta"
    bio.save(m, path, param_in=param_in)
    head = path.read_text().splitlines()[:4]
    assert head == [f"#DIM {len(PARAM_IN[param_in].columns)} 3", f"#PARAM_IN {param_in}", "#PARAM_OUT RGB_COLOR",
                    "#VS 1"]
    back = bio.load(path)
    np.testing.assert_array_equal(back.values, m.values)  # repr-precision numbers: exact
    np.testing.assert_array_equal(back.sigma, m.sigma)
    assert back.channels == ("R", "G", "B")
    np.testing.assert_allclose(back.theta_i, m.theta_i, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.theta_o, m.theta_o, rtol=0, atol=1e-12)
    # an isotropic parameterisation keeps each pair up to a turn about the normal: compare the relative azimuth
    relative = np.exp(1j * (back.phi_o - back.phi_i)) - np.exp(1j * (m.phi_o - m.phi_i))
    assert np.abs(relative).max() < 1e-12
    if PARAM_IN[param_in].fixed_azimuth is None:
        np.testing.assert_allclose(back.wi(), m.wi(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(back.wo(), m.wo(), rtol=0, atol=1e-12)


def polar(v):
    return np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2]), np.arctan2(v[:, 1], v[:, 0])


def test_round_trip_isotropic_pairs_in_their_frame_keep_the_directions(tmp_path, rng):
    theta_i, _, theta_o, phi_o = random_pairs(rng)
    light, view = rusinkiewicz_alta(rng.uniform(0.05, 0.6, 40), rng.uniform(0.05, 0.9, 40), rng.uniform(0, 6.2, 40))
    canonical = {"ISOTROPIC_TL_TV_PROJ_DPHI": (theta_i, 0.0, theta_o, phi_o),
                 "RUSIN_TH_TD_PD": (*polar(light), *polar(view))}  # pairs with φh = 0
    for param_in, angles in canonical.items():
        m = Measurements(*angles, np.arange(1.0, 41.0))
        write_alta(m, tmp_path / "c.alta", param_in=param_in)
        back = read_alta(tmp_path / "c.alta")
        np.testing.assert_allclose(back.wi(), m.wi(), rtol=0, atol=1e-12, err_msg=param_in)
        np.testing.assert_allclose(back.wo(), m.wo(), rtol=0, atol=1e-12, err_msg=param_in)


# ----------------------------------------------------------------------------------------- outputs, error bars
def test_cosine_factor_is_divided_out_and_the_horizon_is_missing(tmp_path):
    theta_v = np.array([0.0, 1.0, math.pi / 2, 0.5])
    rows = np.stack([np.full(4, 0.3), theta_v, np.zeros(4), [0.2, 0.3, 0.4, 0.5], [0.01, 0.02, 0.03, 0.04]], 1)
    m = read_alta(write(tmp_path, "#DIM 3 1\n#VS 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n"
                                  "#PARAM_OUT INV_STERADIAN_COSINE_FACTOR\n" + fmt(rows)))
    np.testing.assert_allclose(m.values[[0, 1, 3], 0], rows[[0, 1, 3], 3] / np.cos(theta_v[[0, 1, 3]]), rtol=1e-15)
    np.testing.assert_allclose(m.sigma[[0, 1, 3], 0], rows[[0, 1, 3], 4] / np.cos(theta_v[[0, 1, 3]]), rtol=1e-15)
    assert np.isnan(m.values[2, 0]) and np.isnan(m.sigma[2, 0])
    assert m.meta["read"]["missing (outgoing direction at or below the horizon)"] == 1
    assert m.meta["alta"]["param_out"] == "INV_STERADIAN_COSINE_FACTOR"
    # writing it back multiplies the cosine in again; the row without a value is left out
    write_alta(m, tmp_path / "back.alta", param_in="ISOTROPIC_TL_TV_PROJ_DPHI",
               param_out="INV_STERADIAN_COSINE_FACTOR")
    back = np.loadtxt(tmp_path / "back.alta", comments="#")
    np.testing.assert_allclose(back[:, 3:], rows[[0, 1, 3], 3:], rtol=1e-15)


def test_colour_outputs_and_vs_forms(tmp_path):
    rows = [[0.1, 0.0, 0.2, 3.0, 0.5, 0.6, 0.7, 0.01, 0.03, 0.02, 0.02, 0.05, 0.01]]
    m = read_alta(write(tmp_path, "#DIM 4 3\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n#PARAM_OUT RGB_COLOR\n#VS 2 2 2\n"
                                  + fmt(rows)))
    assert m.channels == ("R", "G", "B")
    np.testing.assert_allclose(m.sigma[0], [0.02, 0.02, 0.03], rtol=1e-15)  # (below + above) / 2 per output
    assert "half the #VS 2 interval" in m.meta["read"]["sigma"]
    m = read_alta(write(tmp_path, "#DIM 4 3\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n#PARAM_OUT XYZ_COLOR\n#VS 1\n"
                                  + fmt([rows[0][:10]])))
    assert m.channels == ("X", "Y", "Z") and m.sigma[0].tolist() == [0.01, 0.03, 0.02]
    m = read_alta(write(tmp_path, "#DIM 4 2\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n" + fmt([rows[0][:6]])),
                  channels=["lambda=0.4", "lambda=0.5"])
    assert m.channels == ("lambda=0.4", "lambda=0.5") and m.values.tolist() == [[0.5, 0.6]]


def test_writer_keeps_channel_names_drops_missing_rows_and_refuses_partial_rows(tmp_path):
    m = Measurements([0.1, 0.2, 0.3], 0.0, [0.4, 0.5, 0.6], math.pi, [[0.5, 0.25], [np.nan, np.nan], [1.5, 2.0]],
                     channels=("a", "b"))
    bio.save(m, tmp_path / "n.alta")
    lines = (tmp_path / "n.alta").read_text().splitlines()
    assert lines[:5] == ["#DIM 4 2", "#PARAM_IN SPHERICAL_TL_PL_TV_PV", "#PARAM_OUT INV_STERADIAN", "#VS 0",
                         '#BRDFFIT_CHANNELS ["a", "b"]']
    assert lines[5] == "0.1 0.0 0.4 3.141592653589793 0.5 0.25" and len(lines) == 7
    back = bio.load(tmp_path / "n.alta")
    assert back.channels == ("a", "b") and back.n == 2
    with pytest.raises(ValueError, match="row 1 has some channels missing"):
        write_alta(m.replace(values=[[0.5, 0.25], [np.nan, 1.0], [1.5, 2.0]]), tmp_path / "p.alta")
    with pytest.raises(ValueError, match="RGB_COLOR needs 3 channels"):
        write_alta(m, tmp_path / "p.alta", param_out="RGB_COLOR")
    with pytest.raises(ValueError, match="param_in must be one of"):
        write_alta(m, tmp_path / "p.alta", param_in="STEREOGRAPHIC")
    assert not (tmp_path / "p.alta").exists()
    bio.save(m.select_channels("a"), tmp_path / "forced.dat", format="alta")
    assert bio.detect_format(tmp_path / "forced.dat") == "alta"
    # header entries come back from meta["alta"]["header"], never the structural ones; other meta is ignored
    odd = m.replace(meta={"alta": {"header": {"URL": "u", "DIM": "9 9", "CMD": ["a", "b"], "N": 5}}})
    write_alta(odd, tmp_path / "h.alta")
    assert (tmp_path / "h.alta").read_text().splitlines()[:4] == ["#URL u", "#CMD a", "#CMD b", "#DIM 4 2"]
    write_alta(m.replace(meta={"alta": 3}), tmp_path / "h.alta")
    assert read_alta(tmp_path / "h.alta").meta["alta"]["header"] == {}


# ----------------------------------------------------------------------------------------------------- errors
HEADER = "#DIM 4 1\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n"
BAD = [
    ("", r"the file is empty"),
    ("#PARAM_IN SPHERICAL_TL_PL_TV_PV\n0 0 0 0 1\n", r"no #DIM line"),
    ("#DIM 4\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n0 0 0 0 1\n", r"line 1: #DIM needs two positive integers"),
    ("#DIM 4 1\n0 0 0 0 1\n", r"no #PARAM_IN line"),
    ("#DIM 4 1\n#PARAM_IN STEREOGRAPHIC\n0 0 0 0 1\n", r"line 2: #PARAM_IN 'STEREOGRAPHIC' is not a param"),
    ("#DIM 3 1\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n0 0 0 1\n", r"line 1: #DIM declares 3 inputs but #PARAM_IN "
                                                             r"SPHERICAL_TL_PL_TV_PV has 4"),
    (HEADER + "#PARAM_OUT ENERGY\n0 0 0 0 1\n", r"line 3: #PARAM_OUT 'ENERGY' is not an output"),
    ("#DIM 4 2\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n#PARAM_OUT RGB_COLOR\n0 0 0 0 1 1\n",
     r"#DIM declares 2 outputs but #PARAM_OUT RGB_COLOR has 3"),
    (HEADER + "#VS 3\n0 0 0 0 1\n", r"line 3: #VS needs 0, 1 or 2"),
    (HEADER + "#DIM 4 1\n0 0 0 0 1\n", r"line 3: a second #DIM line \(the first is on line 1\)"),
    (HEADER, r"a header but no data rows"),
    (HEADER + "0 0 0 0 1\n0 0 0 1\n0 0 0 0 1\n", r"line 4: 4 numbers where #DIM 4 1 with #VS 0 makes 5"),
    (HEADER + "#VS 1\n0 0 0 0 1\n", r"line 4: 5 numbers where #DIM 4 1 with #VS 1 makes 6: .*then a radius"),
    (HEADER + "0 0 0 0 1\n0 0 0 0", r"line 4: 4 numbers where .* \(truncated\?\)"),
    (HEADER + "0 0 0 0 1\n\n# a comment\n0 0.1 abc 0 1\n", r"line 6, column 3: cannot read 'abc' as a number "
                                                           r"\(input theta_v\)"),
    (HEADER + "#VS 2\n0 0 0 0 1 0.1 x\n", r"line 4, column 7: cannot read 'x' .*distance above of output 1"),
    ("#DIM 6 1\n#PARAM_IN CARTESIAN\n0 0 1 0 0 2 1\n", r"line 3: CARTESIAN L = \[0.0, 0.0, 2.0\] is not a unit"),
    ("#DIM 4 1\n#PARAM_IN SPHERICAL_TL_PL_TV_PV\n#FORMAT binary\n#BEGIN_STREAM\n\0\0\0", r"ALTA binary data"),
    (HEADER + "0 0 0 0 1\0", r"binary data \(a NUL byte at offset 50\)"),
    ("version https://git-lfs.github.com/spec/v1\noid sha256:abc\n", r"Git LFS pointer"),
]


@pytest.mark.parametrize("text, message", BAD)
def test_bad_files_raise_format_error_naming_file_and_place(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(FormatError, match=message) as err:
        read_alta(path)
    assert str(err.value).startswith(str(path))


@pytest.mark.parametrize("rows, message", [
    ("0.1 0 1.7 0 1\n", r"line 4: theta_o: got 1.7 rad .* expected 0 <= theta <= pi/2"),
    ("0.1 0 0.2 0 1\n0.1 0 0.2 0 -0.5\n", r"line 5: values: channel 0 is -0.5; expected f_r >= 0"),
    ("0.1 0 0.2 0 1 0\n", r"line 4: sigma: channel 0 is 0.0; expected a finite sigma > 0"),
])
def test_numbers_out_of_range_raise_measurement_error_with_the_line(tmp_path, rows, message):
    path = write(tmp_path, HEADER + ("#VS 1\n" if len(rows.split()) == 6 else "#PARAM_OUT INV_STERADIAN\n") + rows)
    with pytest.raises(MeasurementError, match=message) as err:
        read_alta(path)
    assert str(err.value).startswith(str(path))


def test_header_markers_comments_and_blank_lines(tmp_path):
    text = ("#ALTA HEADER BEGIN\n#CMD data2data --input x\n\n# free text\n#DIM 4 1\n#CMD second\n"
            "#PARAM_IN SPHERICAL_TL_PL_TV_PV\n#ALTA END HEADER\n#DIM 9 9\n0 0 0.5 1 0.25\n#later\n0 0 0.6 1 0.5\n")
    m = read_alta(write(tmp_path, text))
    assert m.n == 2 and m.values[:, 0].tolist() == [0.25, 0.5]
    assert m.meta["alta"]["header"] == {"CMD": ["data2data --input x", "second"]}
    assert m.meta["alta"]["comments"] == ["free text", "DIM 9 9", "later"]
