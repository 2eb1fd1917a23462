"""CSV / TSV tables: canonical layout, column mappings, filters, the NIST PTFE file, and clear errors."""

import csv
import math
import os
from pathlib import Path

import numpy as np
import pytest

import brdffit.io as bio
from brdffit.io import FormatError, read_table, write_table
from brdffit.measurements import MeasurementError, Measurements

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
NIST = SHARED / "nist-ptfe" / "PTFE.data.csv"
NIST_COLUMNS = {"theta_i": "thetai", "phi_i": "phi", "theta_o": "thetar", "phi_o": "phir"}


def nist_file() -> Path:
    if not NIST.exists():
        pytest.skip(f"{NIST} not found: real-data tests need ../shared beside the project")
    return NIST


def write(tmp_path, text, name="t.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def sample(sigma=True, weights=True):
    deg = np.array([[0, 0, 30, 180], [15, 90, 45.5, 270], [75, 359.5, 80, 12.25]], dtype=float)
    values = np.array([[0.5, 0.25, 0.125], [0.3, np.nan, 0.1], [1e-5, 2.5, 3.0]])
    return Measurements(*np.radians(deg.T), values, sigma=values * 0.1 + 0.01 if sigma else None,
                        weights=np.array([1.0, 0.5, 0.25]) if weights else None,
                        meta={"instrument": "test", "truth": {"spec": "lambert", "params": {"rho_d": [0.5]}}})


def test_canonical_round_trip_is_exact(tmp_path):
    m = sample()
    path = tmp_path / "x.csv"
    bio.save(m, path)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#") and lines[1].startswith("# brdffit-meta:")
    assert lines[2] == "theta_i,phi_i,theta_o,phi_o,R,G,B,sigma_R,sigma_G,sigma_B,weights"
    assert lines[4].split(",")[:7] == ["15", "90", "45.5", "270", "0.3", "nan", "0.1"]
    back = bio.load(path)
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values", "sigma", "weights"):
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name), err_msg=name)
    assert back.channels == ("R", "G", "B")
    assert back.meta["truth"] == m.meta["truth"] and back.meta["source"] == str(path)


def test_tsv_and_no_sigma(tmp_path):
    m = sample(sigma=False, weights=False)
    path = tmp_path / "x.tsv"
    bio.save(m, path)
    assert "\t" in path.read_text().splitlines()[2]
    back = bio.load(path)
    assert back.sigma is None and back.weights is None
    np.testing.assert_array_equal(back.values, m.values)


def test_headerless_whitespace_table_is_positional(tmp_path):
    path = write(tmp_path, "# a comment\n30 0 30 180 0.5 0.6\n\n-45 0 10 90 0.25 0.3\n", "t.txt")
    m = read_table(path)
    assert m.channels == ("c0", "c1")
    np.testing.assert_allclose(np.degrees(m.theta_i), [30, 45])
    np.testing.assert_allclose(np.degrees(m.phi_i), [0, 180])  # negative θ: azimuth + 180°
    assert m.values.tolist() == [[0.5, 0.6], [0.25, 0.3]]
    assert m.meta["comments"] == ["a comment"]
    # indices name the columns of a headerless file
    m2 = read_table(path, columns={"theta_i": 2, "phi_i": 3, "theta_o": 0, "phi_o": 1}, values=[5])
    np.testing.assert_allclose(np.degrees(m2.theta_o), [30, 45])
    assert m2.values[:, 0].tolist() == [0.6, 0.3]


def test_negative_polar_angles_flip_azimuth(tmp_path):
    path = write(tmp_path, "theta_i,phi_i,theta_o,phi_o,f\n-30,0,-20,10,0.5\n-15,270,40,-90,0.4\n")
    m = read_table(path)
    np.testing.assert_allclose(np.degrees(m.theta_i), [30, 15])
    np.testing.assert_allclose(np.degrees(m.phi_i), [180, 90])
    np.testing.assert_allclose(np.degrees(m.theta_o), [20, 40])
    np.testing.assert_allclose(np.degrees(m.phi_o), [190, 270])


def test_radians_mapping_sigma_and_where(tmp_path):
    text = "ti;pi;to;po;band;f;err;label\n0.5;0;0.5;3.14;1;0.2;0.01;a\n0.5;0;0.7;3.14;2;0.3;0.02;b\n"
    path = write(tmp_path, text, "t.dat")
    m = read_table(path, columns={"theta_i": "ti", "phi_i": "pi", "theta_o": "to", "phi_o": "po"},
                   values="f", sigma="err", where={"band": 2}, degrees=False)
    assert m.n == 1 and m.theta_o[0] == 0.7 and m.phi_o[0] == 3.14
    assert m.values[0, 0] == 0.3 and m.sigma[0, 0] == 0.02 and m.channels == ("f",)
    assert m.meta["reader"]["where"] == {"band": 2}
    by_text = read_table(path, columns={"theta_i": "ti", "phi_i": "pi", "theta_o": "to", "phi_o": "po"},
                         values="f", where={"label": "a"}, degrees=False, channels=["red"])
    assert by_text.values[0, 0] == 0.2 and by_text.channels == ("red",)
    with pytest.raises(FormatError, match=r"no row has band = 3 .*values in that column: 1.0, 2.0"):
        read_table(path, columns={"theta_i": "ti", "phi_i": "pi", "theta_o": "to", "phi_o": "po"}, values="f",
                   where={"band": 3})


def test_canonical_auto_skips_text_columns_and_maps_negative_to_missing(tmp_path):
    path = write(tmp_path, "theta_i,phi_i,theta_o,phi_o,note,R\n0,0,10,0,x,0.5\n0,0,20,0,y,-1\n")
    with pytest.raises(MeasurementError) as info:
        read_table(path)
    assert str(info.value).startswith(f"{path}: line 3: values (column 'R'): channel 0 is -1.0;")
    m = read_table(path, negative="missing")
    assert m.channels == ("R",) and np.isnan(m.values[1, 0]) and m.meta["reader"]["negative_as_missing"] == 1


def test_channel_column_pivot(tmp_path):
    text = "lam,thetai,phi,thetar,phir,f\n0.5,0,0,10,0,0.1\n0.6,0,0,10,0,0.2\n0.5,0,0,20,0,0.3\n"
    path = write(tmp_path, text)
    m = read_table(path, columns=NIST_COLUMNS, values="f", channel_column="lam")
    assert m.channels == ("lam=0.5", "lam=0.6")
    np.testing.assert_array_equal(m.values, [[0.1, 0.2], [0.3, np.nan]])
    dup = write(tmp_path, text + "0.5,0,0,10,0,0.9\n", "dup.csv")
    with pytest.raises(FormatError, match="line 5: two rows with lam = 0.5 at the same angles"):
        read_table(dup, columns=NIST_COLUMNS, values="f", channel_column="lam")


@pytest.mark.parametrize("text, pattern", [
    ("", "the file is empty"),
    ("   \n\n", "the file is empty"),
    ("# only a comment\n", "no table rows"),
    ("theta_i,phi_i,theta_o,phi_o,R\n", "a header but no data rows"),
    ("theta_i,phi_i,theta_o,phi_o,R\n0,0,10,0,0.5\n0,0,20,0,0.4\n0,0,30\n",
     r"line 4: 3 cells where the header has 5 \(truncated\?\)"),
    ("theta_i,phi_i,theta_o,phi_o,R\n0,0,10,0,0.5\n0,0,2O,0,0.4\n",
     r"line 3, column 3 \('theta_o'\): cannot read '2O' as a number"),
    ("theta_i,phi_i,theta_o,phi_o,R\n0,0,10,0,0.5\n0,0,20,0,0.4x\n", r"line 3, column 5 \('R'\): cannot read '0.4x'"),
    ("theta_i,phi_i,theta_o,phi_o,R\n0,,10,0,0.5\n", r"line 2, column 2 \('phi_i'\): empty or missing cell"),
    ("thetai,phi_i,theta_o,phi_o,R\n0,0,10,0,0.5\n", r"angle theta_i: no column 'theta_i' \(columns: thetai, phi_i"),
    ("theta_i,phi_i,theta_o,theta_o,R\n0,0,10,0,0.5\n", "header names column 'theta_o' twice"),
    ("theta_i,phi_i,theta_o,phi_o,sigma_R\n0,0,10,0,0.5\n", "no value column"),
    ("theta_i,phi_i,theta_o,phi_o,R,G,sigma_R\n0,0,10,0,0.5,0.5,0.1\n", "no 'sigma_G'"),
    ("1 2 3 4\n", "at least one value column"),
    ("version https://git-lfs.github.com/spec/v1\noid sha256:abc\nsize 123\n", "Git LFS pointer"),
])
def test_bad_tables(tmp_path, text, pattern):
    path = write(tmp_path, text)
    with pytest.raises(FormatError, match=pattern) as info:
        bio.load(path)
    assert str(info.value).startswith(str(path))


def test_binary_and_non_utf8_tables(tmp_path):
    path = tmp_path / "b.csv"
    path.write_bytes(b"theta_i,phi_i\x00\x01")
    with pytest.raises(FormatError, match="NUL byte at offset 13"):
        read_table(path)
    path.write_bytes(b"theta_i,phi_i,theta_o,phi_o,R\n0,0,10,0,\xff\n")
    with pytest.raises(FormatError, match="not UTF-8 text"):
        read_table(path)


def test_angles_out_of_range_name_the_line(tmp_path):
    path = write(tmp_path, "theta_i,phi_i,theta_o,phi_o,R\n0,0,10,0,0.5\n0,0,95,0,0.5\n")
    with pytest.raises(MeasurementError, match=r"t.csv: line 3: theta_o \(column 'theta_o'\).*95 deg"):
        read_table(path)


def test_writers_never_damage_an_existing_file(tmp_path, monkeypatch):
    path = tmp_path / "x.csv"
    path.write_text("precious\n")

    class Boom:
        def __init__(self, *a, **k):
            pass

        def writerow(self, row):
            pass

        def writerows(self, rows):
            raise RuntimeError("disk full")

    monkeypatch.setattr(csv, "writer", Boom)
    with pytest.raises(RuntimeError, match="disk full"):
        write_table(sample(), path)
    assert path.read_text() == "precious\n"
    assert os.listdir(tmp_path) == ["x.csv"]  # no temporary file left behind


def test_channel_names_that_clash_are_refused(tmp_path):
    m = sample().replace(channels=("R", "sigma_x", "B"))
    with pytest.raises(ValueError, match="clashes"):
        write_table(m, tmp_path / "x.csv")


# ------------------------------------------------------------------------------------------- the NIST PTFE file
def test_nist_one_line_load():
    m = bio.load(nist_file(), columns=NIST_COLUMNS, values="f_r11", where={"lambda": 0.532})
    assert m.n == 1824 and m.channels == ("f_r11",)
    # file line 1826: 0.532,-0.001,0,80.0258,-156.038,2.65E-01 (θi = -0.001: the source sits at azimuth 180°)
    np.testing.assert_allclose(np.degrees([m.theta_i[0], m.phi_i[0], m.theta_o[0], m.phi_o[0]]),
                               [0.001, 180.0, 80.0258, 360 - 156.038], rtol=1e-14)
    assert m.values[0, 0] == 0.265
    assert m.meta["reader"]["where"] == {"lambda": 0.532}
    assert set(np.round(np.degrees(np.unique(m.theta_i)), 9)) == {0.001, 15, 30, 45, 60, 75}
    assert np.all(np.degrees(m.phi_i) == 180.0)
    assert math.pi * np.median(m.values) == pytest.approx(0.9865, abs=1e-3)  # near-Lambertian white: π f ≈ 1


def test_nist_four_wavelengths_as_channels():
    m = bio.load(nist_file(), columns=NIST_COLUMNS, values="f_r11", channel_column="lambda")
    assert m.n == 1824
    assert m.channels == ("lambda=0.351", "lambda=0.532", "lambda=0.633", "lambda=1.064")
    assert m.values[0].tolist() == [0.262, 0.265, 0.267, 0.272]
    assert m.values[-1].tolist()[-1] == 0.654  # last line: 1.064,-75,0,80.0258,23.9625,6.54E-01
    one = bio.load(nist_file(), columns=NIST_COLUMNS, values="f_r11", where={"lambda": 1.064})
    np.testing.assert_array_equal(one.values[:, 0], m.values[:, 3])
    np.testing.assert_array_equal(one.theta_o, m.theta_o)


def test_nist_round_trip_gives_back_the_files_numbers(tmp_path):
    path = nist_file()
    m = bio.load(path, columns=NIST_COLUMNS, values="f_r11", where={"lambda": 0.532})
    out = tmp_path / "ptfe532.csv"
    bio.save(m, out)
    back = bio.load(out)
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values"):
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name), err_msg=name)
    raw = np.genfromtxt(path, delimiter=",", names=True)
    raw = raw[raw["lambda"] == 0.532]
    mine = np.genfromtxt(out, delimiter=",", names=True, skip_header=2)
    assert np.array_equal(mine["theta_i"], np.abs(raw["thetai"]))
    assert np.array_equal(mine["phi_i"], np.where(raw["thetai"] < 0, raw["phi"] + 180, raw["phi"]))
    assert np.array_equal(mine["theta_o"], raw["thetar"])
    # the azimuth wraps into [0, 360): -110.556 + 360 = 249.44400000000002 comes back one ulp away on 6 rows
    np.testing.assert_allclose(mine["phi_o"], np.mod(raw["phir"], 360), rtol=2e-16, atol=0)
    assert np.count_nonzero(mine["phi_o"] != np.mod(raw["phir"], 360)) <= 6
    assert np.array_equal(mine["f_r11"], raw["f_r11"])


@pytest.mark.parametrize("delimiter", [",", "\t", " "])
def test_an_all_number_table_is_read_as_one_array_with_the_values_cell_by_cell_reading_gives(tmp_path, delimiter):
    """The one-array reading (`numpy.loadtxt`) of a table of plain numbers gives what the cell-by-cell reading
    gives: the same table with one missing marker ("NA") takes that path, and every other value agrees exactly;
    a cell with a digit group ("1_0") still is an error naming its line and column."""
    from brdffit.io.table import _read_text, _split_lines

    rng = np.random.default_rng(4)
    angles = np.column_stack([rng.uniform(0, 80, 40), rng.uniform(0, 360, 40), rng.uniform(0, 80, 40),
                              rng.uniform(0, 360, 40)])
    values = rng.uniform(0.01, 3.0, 40)
    cells = [[f"{a:.9g}" for a in row] + [f"{v:.6e}" if r % 3 else f"+{v:.9g}"] for r, (row, v) in
             enumerate(zip(angles, values))]
    header = ["theta_i", "phi_i", "theta_o", "phi_o", "R"]

    def write(name, rows):
        path = tmp_path / name
        path.write_text("# a gonio scan\n" + delimiter.join(header) + "\n"
                        + "\n".join(delimiter.join(row) for row in rows) + "\n")
        return path

    fast_path = write("fast.txt", cells)
    slow_path = write("slow.txt", cells[:-1] + [cells[-1][:4] + ["NA"]])
    assert _split_lines(fast_path, _read_text(fast_path), None)._rows is None  # read as one array
    assert _split_lines(slow_path, _read_text(slow_path), None)._rows is not None  # cell by cell
    fast, slow = read_table(fast_path), read_table(slow_path)
    np.testing.assert_array_equal(fast.values[:-1], slow.values[:-1])
    np.testing.assert_array_equal(fast.values[:, 0], [float(row[4]) for row in cells])  # as Python reads each
    for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name))
    assert np.isnan(slow.values[-1, 0])
    bad = write("bad.txt", cells[:5] + [cells[5][:4] + ["1_0"]] + cells[6:])
    with pytest.raises(FormatError, match=r"line 8.*column 5 \('R'\)|column 5 \('R'\).*line 8"):
        read_table(bad)
