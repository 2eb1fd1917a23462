"""brdffit.io.astm: ASTM E1392 files read and written (hand-written fixtures in tests/data/astm/), the angle unit
decided and said, wavelengths kept, and bad files refused naming the file, the line and what was expected."""

import math
from pathlib import Path

import numpy as np
import pytest

import brdffit.io as bio
from brdffit.cli import EXIT_BAD_INPUT, EXIT_OK, main
from brdffit.io import FormatError
from brdffit.measurements import MeasurementError, Measurements

DATA = Path(__file__).resolve().parent / "data" / "astm"


def test_cornell_layout_is_read_with_its_header_bands_and_signed_angles():
    m = bio.load(DATA / "cornell_like.astm")
    assert bio.detect_format(DATA / "cornell_like.astm") == "astm"
    assert m.n == 4 and m.channels == ("400nm", "500nm", "600nm")
    assert m.meta["wavelengths_nm"] == [400.0, 500.0, 600.0]
    header = m.meta["astm"]["header"]
    assert header["SAMPLE_NAME"] == "blue paint (invented values)" and header["MEAS_NAME"] == "gonio-2"
    assert m.meta["read"]["angles"].startswith("radians, as the standard writes them")
    np.testing.assert_allclose(m.theta_i, [0.0, 0.5236, 0.5236, 0.7854])
    # Row 3 gives θs = −0.3491 at φs = 0: the direction at 0.3491 on the far side of the normal.
    assert m.theta_o[2] == pytest.approx(0.3491) and m.phi_o[2] == pytest.approx(math.pi)
    # Row 4's 500 nm cell is empty: a missing value.
    assert np.isnan(m.values[3, 1]) and m.values[3, 2] == pytest.approx(0.0590)


def test_degrees_are_decided_from_the_data_or_given():
    m = bio.load(DATA / "degrees.astm")  # whitespace-separated, θ up to 60: degrees
    assert m.channels == ("R", "G", "B") and "wavelengths_nm" not in m.meta
    assert m.meta["read"]["angles"].startswith("degrees (some |θ| reaches 60 > π/2")
    np.testing.assert_allclose(m.theta_i, np.radians([0, 30, 60]))
    with pytest.raises(FormatError, match=r"degrees.astm: angles given in radians must have \|θ\| ≤ π/2"):
        bio.load(DATA / "degrees.astm", degrees=False)
    radians = bio.load(DATA / "cornell_like.astm", degrees=True)  # small numbers read as degrees when told so
    assert radians.theta_i[1] == pytest.approx(math.radians(0.5236))
    assert radians.meta["read"]["angles"] == "degrees (as given)"


def test_round_trip_keeps_angles_values_missing_cells_and_header(tmp_path):
    m = bio.load(DATA / "cornell_like.astm")
    path = tmp_path / "copy.astm"
    bio.save(m, path)
    back = bio.load(path)
    for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name))
    np.testing.assert_array_equal(back.values, m.values)  # NaN where it was
    assert back.channels == m.channels and back.meta["wavelengths_nm"] == m.meta["wavelengths_nm"]
    assert back.meta["astm"]["header"] == {**m.meta["astm"]["header"], "NUM_POINTS": "4"}
    text = path.read_text()
    assert "VARS theta_i,phi_i,theta_s,phi_s,400nm,500nm,600nm\n" in text and 'SAMPLE_NAME "blue paint' in text


def test_measurements_from_code_are_written_in_radians(tmp_path):
    m = Measurements(np.radians([10, 40]), 0.0, np.radians([20, 50]), np.pi, [[0.1], [0.2]], channels=["550nm"])
    path = tmp_path / "new.astm"
    bio.save(m, path)
    lines = path.read_text().splitlines()
    assert lines[:3] == ["SOURCE brdffit", "NUM_POINTS 2", "VARS theta_i,phi_i,theta_s,phi_s,550nm"]
    back = bio.load(path)
    np.testing.assert_array_equal(back.theta_o, m.theta_o)
    assert back.meta["wavelengths_nm"] == [550.0]


@pytest.mark.parametrize("name, text, message", [
    ("truncated_row.astm", None, r"truncated_row.astm: line 4: 5 cells where VARS names 6 \(theta_i, phi_i, "
                                 r"theta_s, phi_s, 400nm, 500nm\) \(truncated\?\)"),
    ("truncated_file.astm", None, r"truncated_file.astm: NUM_POINTS says 3 rows but the file has 2 \(truncated\?\)"),
    ("novars.astm", "SAMPLE_NAME x\n0,0,0.1,3.1,0.2\n", r"novars.astm: line 2: a header line that is not 'KEYWORD "
                                                        r"value'"),
    ("order.astm", "VARS phi_i,theta_i,theta_s,phi_s,R\n0,0,0.1,3.1,0.2\n",
     r"order.astm: line 1: VARS column 1 is 'phi_i'; the standard's angle columns are theta_i, phi_i"),
    ("cell.astm", "VARS theta_i,phi_i,theta_s,phi_s,R\n0,0,0.1,3.1,abc\n",
     r"cell.astm: line 2, column 5 \('R'\): cannot read 'abc' as a number"),
    ("grouped.astm", "VARS theta_i,phi_i,theta_s,phi_s,R\n0,0,0.1,3.1,1_000\n",  # float() would read 1000
     r"grouped.astm: line 2, column 5 \('R'\): cannot read '1_000' as a number"),
    ("angle.astm", "VARS theta_i,phi_i,theta_s,phi_s,R\n0,,0.1,3.1,0.2\n",
     r"angle.astm: line 2, column 2 \('phi_i'\): angle phi_i is '': the angles must be numbers"),
    ("range.astm", "VARS theta_i,phi_i,theta_s,phi_s,R\n120,0,10,180,0.2\n",
     r"range.astm: the angles fit neither radians"),
])
def test_bad_files_are_refused_naming_file_line_and_expectation(tmp_path, name, text, message):
    path = DATA / name if text is None else tmp_path / name
    if text is not None:
        path.write_text(text)
    with pytest.raises(FormatError, match=message):
        bio.load(path)


def test_a_negative_value_names_its_line(tmp_path):
    path = tmp_path / "negative.astm"
    path.write_text("VARS theta_i,phi_i,theta_s,phi_s,R\n0,0,0.1,3.1,0.2\n0,0,0.2,3.1,-0.5\n")
    with pytest.raises(MeasurementError, match=r"negative.astm: line 3"):
        bio.load(path)


def test_cli_reads_astm_and_its_angle_options(tmp_path, capsys):
    assert main(["info", str(DATA / "cornell_like.astm")]) == EXIT_OK
    out = capsys.readouterr().out
    assert "4 samples x 3 channels (400nm, 500nm, 600nm)" in out and "angles: radians" in out
    assert main(["info", str(DATA / "degrees.astm"), "--radians"]) == EXIT_BAD_INPUT
    assert "angles given in radians" in capsys.readouterr().err
    converted = tmp_path / "c.h5"
    assert main(["convert", str(DATA / "cornell_like.astm"), str(converted), "--degrees"]) == EXIT_OK
    assert bio.load(converted).meta["wavelengths_nm"] == [400.0, 500.0, 600.0]
    table = tmp_path / "t.csv"
    table.write_text("theta_i,phi_i,theta_o,phi_o,R\n10,0,20,180,0.3\n")
    assert main(["info", str(table), "--degrees"]) == EXIT_BAD_INPUT
    assert "--degrees applies to ASTM E1392 files only" in capsys.readouterr().err
