"""MERL binary tables: index mapping, cell measure, write -> read -> lookup round trips, bad files."""

import math

import numpy as np
import pytest

import brdffit
import brdffit.io as bio
from brdffit.geometry import to_half_diff
from brdffit.io import FormatError, MerlTable, read_merl, write_merl
from brdffit.io import merl

N = 90 * 90 * 180


@pytest.fixture(scope="module")
def glossy():
    return brdffit.models.get("lambert+ggx", rho_d=[0.5, 0.3, 0.2], ks=[0.3, 0.35, 0.4], alpha=0.3)


@pytest.fixture(scope="module")
def glossy_file(glossy, tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "glossy.binary"
    write_merl(glossy, path)
    return path


@pytest.fixture(scope="module")
def glossy_table(glossy_file):
    return read_merl(glossy_file)


def test_index_rules_at_known_angles():
    deg = math.radians
    assert merl.theta_h_index([0.0, deg(1.0), deg(45.0), deg(89.99), math.pi / 2, 2.0]).tolist() == [
        0, 9, 63, 89, 89, 89]  # ⌊√(θh/90°)·90⌋: 1° -> 9.49, 45° -> 63.6
    assert merl.theta_d_index([0.0, deg(0.99), deg(1.0), deg(45.5), deg(90.0)]).tolist() == [0, 0, 1, 45, 89]
    # φd folds by reciprocity: φd and φd + π share a cell
    assert merl.phi_d_index([0.0, deg(90.5), deg(180.0), deg(270.5), deg(359.9), -deg(0.5)]).tolist() == [
        0, 90, 0, 90, 179, 179]


def test_cell_centres_map_back_to_their_cells():
    i, j, k = np.arange(90), np.arange(90), np.arange(180)
    assert np.array_equal(merl.theta_h_index(merl.theta_h_centre(i)), i)
    assert np.array_equal(merl.theta_d_index(merl.theta_d_centre(j)), j)
    assert np.array_equal(merl.phi_d_index(merl.phi_d_centre(k)), k)
    assert np.array_equal(merl.phi_d_index(merl.phi_d_centre(k) + math.pi), k)
    assert merl.theta_h_centre(0) == pytest.approx((0.5 / 90) ** 2 * math.pi / 2, rel=1e-15)
    assert merl.theta_h_centre(89) == pytest.approx((89.5 / 90) ** 2 * math.pi / 2, rel=1e-15)
    # the centre is the midpoint in the square-root scale, not in θh
    assert merl.theta_h_centre(1) == pytest.approx(math.radians(90 * (1.5 / 90) ** 2))


def test_cell_angles_are_the_centres_in_half_diff_space():
    ti, pi_, to, po = (a[[3, 40, 80], [10, 20, 60], [5, 90, 170]] for a in merl.cell_angles(0.0))
    th, ph, td, pd = (np.asarray(a) for a in to_half_diff(ti, pi_, to, po))
    np.testing.assert_allclose(th, merl.theta_h_centre([3, 40, 80]), rtol=1e-12, atol=1e-13)  # arccos near 0
    np.testing.assert_allclose(td, merl.theta_d_centre([10, 20, 60]), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(pd, merl.phi_d_centre([5, 90, 170]), rtol=1e-12)


def test_cell_measure():
    w = merl.cell_weights()
    assert w.shape == (90, 90, 180) and np.all(w > 0)
    assert w.sum() == pytest.approx(8 * math.pi ** 2, rel=1e-12)  # all pairs whose half vector is above
    ti, _, to, _ = merl.cell_angles(0.0)
    above = (ti < math.pi / 2) & (to < math.pi / 2)
    assert w[above].sum() == pytest.approx(4 * math.pi ** 2, rel=1e-3)  # the two hemispheres, (2π)²
    # Monte Carlo: uniform pairs of hemisphere directions (measure 4π²) landing in cells θh index < 30, θd < 30,
    # all wholly above the horizon (θi <= θh + θd <= 40°)
    rng = np.random.default_rng(7)
    n = 400_000
    cos_i, cos_o = rng.random((2, n))
    phi_i, phi_o = rng.random((2, n)) * 2 * math.pi
    th, _, td, _ = (np.asarray(a) for a in to_half_diff(np.arccos(cos_i), phi_i, np.arccos(cos_o), phi_o))
    hits = (merl.theta_h_index(th) < 30) & (merl.theta_d_index(td) < 30)
    estimate = hits.mean() * 4 * math.pi ** 2
    exact = w[:30, :30, :].sum()
    assert estimate == pytest.approx(exact, rel=0.05)
    assert exact == pytest.approx(4 * math.pi * (1 - math.cos(math.pi / 18)) * (1 - math.cos(math.pi / 3)) * math.pi,
                                  rel=1e-12)


def test_written_file_layout(glossy, glossy_file):
    data = glossy_file.read_bytes()
    assert len(data) == 12 + 3 * N * 8 == 34_992_012
    assert np.frombuffer(data[:12], "<i4").tolist() == [90, 90, 180]
    raw = np.frombuffer(data, "<f8", offset=12).reshape(3, 90, 90, 180)
    i, j, k = 20, 30, 45
    th, td, pd = merl.theta_h_centre(i), merl.theta_d_centre(j), merl.phi_d_centre(k)
    ti, pi_, to, po = brdffit.geometry.from_half_diff(th, 0.0, td, pd)
    f = np.asarray(brdffit.evaluate(glossy, ti, pi_, to, po))
    np.testing.assert_allclose(raw[:, i, j, k] * np.array(merl.SCALES), f, rtol=1e-14)
    # cells with a centre below the horizon hold the MERL "no value" marker
    ti, _, to, _ = merl.cell_angles(0.0)
    below = (ti >= math.pi / 2) | (to >= math.pi / 2)
    assert np.all(raw[:, below] == -1.0) and np.all(raw[:, ~below] > 0)
    assert int(below.sum()) == 361_784


def test_read_masks_missing_cells_and_looks_up_centres(glossy, glossy_table):
    t = glossy_table
    assert t.data.shape == (3, 90, 90, 180) and not t.data.flags.writeable
    assert np.isnan(t.data).any(axis=0).sum() == 361_784
    ti, pi_, to, po = (a[::7, ::11, ::13].reshape(-1) for a in merl.cell_angles(0.0))
    keep = (ti < math.pi / 2) & (to < math.pi / 2)
    ti, pi_, to, po = ti[keep], pi_[keep], to[keep], po[keep]
    np.testing.assert_allclose(t.lookup(ti, pi_, to, po), np.asarray(brdffit.evaluate(glossy, ti, pi_, to, po)),
                               rtol=1e-12)


def test_lookup_at_random_angles(glossy, glossy_table):
    rng = np.random.default_rng(3)
    n = 20_000
    ti, to = np.arccos(rng.random((2, n)))
    pi_, po = rng.random((2, n)) * 2 * math.pi
    got = glossy_table.lookup(ti, pi_, to, po)
    assert got.shape == (n, 3)
    # exactly the value of the containing cell (nearest-cell lookup, evaluated at the cell centre)
    th, _, td, pd = (np.asarray(a) for a in to_half_diff(ti, pi_, to, po))
    i, j, k = merl.theta_h_index(th), merl.theta_d_index(td), merl.phi_d_index(pd)
    ci, cpi, co, cpo = brdffit.geometry.from_half_diff(merl.theta_h_centre(i), 0.0, merl.theta_d_centre(j),
                                                       merl.phi_d_centre(k))
    centre = np.asarray(brdffit.evaluate(glossy, ci, cpi, co, cpo))
    ok = np.isfinite(got[:, 0])
    assert 0.99 < ok.mean() < 1.0  # a few grazing samples fall in cells whose centre is below the horizon
    np.testing.assert_allclose(got[ok], centre[ok], rtol=1e-9)
    # and close to the model itself: the tabulation error of a 90 x 90 x 180 grid
    rel = np.abs(got[ok] / np.asarray(brdffit.evaluate(glossy, ti, pi_, to, po))[ok] - 1)
    assert np.median(rel) < 1e-3 and np.percentile(rel, 99) < 0.05
    # below the horizon the BRDF is zero
    assert glossy_table.lookup(1.7, 0.0, 0.3, 0.0).tolist() == [0.0, 0.0, 0.0]


def test_lambert_round_trips_exactly(tmp_path):
    model = brdffit.models.get("lambert", channels=1, rho_d=[0.6])
    path = tmp_path / "grey.merl"
    write_merl(model, path)
    table = read_merl(path)
    rng = np.random.default_rng(0)
    ti, to = np.arccos(rng.uniform(0.05, 1.0, (2, 1000)))
    got = table.lookup(ti, 0.3, to, 2.0)
    ok = np.isfinite(got[:, 0])
    np.testing.assert_allclose(got[ok], 0.6 / math.pi, rtol=1e-15)
    assert ok.mean() > 0.99


def test_to_measurements(glossy_table):
    m = glossy_table.grid_measurements()
    ti, _, to, _ = merl.cell_angles(0.0)
    n_above = int(((ti < math.pi / 2) & (to < math.pi / 2)).sum())
    assert m.n == n_above == N - 361_784
    assert m.channels == ("R", "G", "B") and m.meta["format"] == "merl"
    assert m.weights.sum() == pytest.approx(4 * math.pi ** 2, rel=1e-3)
    assert m.meta["cells"]["missing"] == 361_784
    sub = glossy_table.grid_measurements(subsample=5000, seed=1)
    again = glossy_table.grid_measurements(subsample=5000, seed=1)
    assert sub.n == 5000 and np.array_equal(sub.values, again.values)
    assert not np.array_equal(sub.theta_o, glossy_table.grid_measurements(subsample=5000, seed=2).theta_o)
    np.testing.assert_array_equal(glossy_table.lookup(sub.theta_i, sub.phi_i, sub.theta_o, sub.phi_o), sub.values)
    del m


def test_table_round_trip_is_exact_and_negative_cells_are_missing(tmp_path):
    rng = np.random.default_rng(5)
    data = rng.uniform(0.0, 3.0, (3, 90, 90, 180))
    data[0, 1, 2, 3] = np.nan
    data[:, 50, 60, 70] = np.nan
    path = tmp_path / "t.binary"
    MerlTable(data).write(path)
    table = bio.merl.read_merl(path)
    np.testing.assert_allclose(table.data, data, rtol=2.3e-16, atol=0)
    assert np.array_equal(np.isnan(table.data), np.isnan(data))
    # a stored negative number of any size is missing, never clamped to 0
    raw = bytearray(path.read_bytes())
    raw[12 + 8 * 7:12 + 8 * 8] = np.array([-0.001]).tobytes()
    path.write_bytes(bytes(raw))
    assert np.isnan(read_merl(path).data.reshape(3, -1)[0, 7])


def test_model_channels(tmp_path):
    with pytest.raises(ValueError, match="3 channels"):
        write_merl(brdffit.models.get("lambert", channels=2), tmp_path / "x.binary")
    with pytest.raises(TypeError):
        write_merl("lambert", tmp_path / "x.binary")
    assert not (tmp_path / "x.binary").exists()


def _header(dims=(90, 90, 180)):
    return np.asarray(dims, "<i4").tobytes()


@pytest.mark.parametrize("content, pattern", [
    (b"", "shorter than the 12-byte MERL header"),
    (_header()[:7], "7 bytes: shorter than the 12-byte MERL header"),
    (_header((90, 90, 360)), r"dimensions are \(90, 90, 360\), expected \(90, 90, 180\)"),
    (_header((180, 90, 90)) + b"\0" * 24, "dimensions are"),
    (_header() + b"\0" * 800, "812 bytes where a MERL file has 34,992,012 .*truncated"),
    (b"version https://git-lfs.github.com/spec/v1\noid sha256:0\nsize 34992012\n", "Git LFS pointer"),
])
def test_bad_files(tmp_path, content, pattern):
    path = tmp_path / "bad.binary"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=pattern) as info:
        bio.load(path)
    assert str(info.value).startswith(str(path))


def test_trailing_bytes_and_infinite_values(tmp_path, glossy_file):
    path = tmp_path / "long.binary"
    data = glossy_file.read_bytes()
    path.write_bytes(data + b"\0" * 8)
    with pytest.raises(FormatError, match="trailing data"):
        read_merl(path)
    raw = bytearray(data)
    offset = 12 + 8 * (N + 5)  # the green table, cell (0, 0, 5)
    raw[offset:offset + 8] = np.array([np.inf]).tobytes()
    path.write_bytes(bytes(raw))
    with pytest.raises(FormatError, match=r"infinite value in channel G at cell \(θh 0, θd 0, φd 5\)"):
        read_merl(path)


def test_load_dispatch_and_save_refusal(tmp_path, glossy_file):
    sniffed = tmp_path / "noext"
    sniffed.symlink_to(glossy_file)
    m = bio.load(sniffed, pairs=100, seed=0)
    assert 80 < m.n <= 100 and m.channels == ("R", "G", "B")  # a few peak pairs leave the cone (io.tabulated)
    assert bio.detect_format(sniffed) == "merl"
    with pytest.raises(ValueError, match="write_merl"):
        bio.save(m, tmp_path / "out.binary")
