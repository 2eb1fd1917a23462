"""The command line: the Quick start job end to end, info, models, and exit codes on bad input."""

import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from brdffit import FitResult, io, synth
from brdffit.cli import EXIT_BAD_INPUT, EXIT_NOT_CONVERGED, EXIT_OK, main

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "data" / "synthetic" / "plastic.h5"


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path / "jax-cache"))


def test_quick_start_fit_recovers_the_shipped_plastic(tmp_path, capsys):
    out = tmp_path / "plastic"
    # The README's main job: with no options, model selection over the standard candidates picks the truth.
    assert main(["fit", str(PLASTIC), "--out", str(out), "--json"]) == EXIT_OK
    printed = json.loads(capsys.readouterr().out)
    assert set(printed) == {"model", "params", "stderr", "posterior", "metrics", "status", "files"}
    assert printed["model"] == "lambert+cook-torrance"
    assert printed["status"] == "converged"
    assert json.loads((out / "selection.json").read_text())["chosen"] == "lambert+cook-torrance"
    truth = synth.truth_model(io.load(PLASTIC)).params
    assert printed["params"]["m"] == pytest.approx(float(truth["m"]), rel=0.01)
    np.testing.assert_allclose(printed["params"]["rho_d"], truth["rho_d"], rtol=0.01)
    # Everything it wrote reads back: the measurements and the fit in one HDF5 file, JSON and text summaries.
    result = FitResult.load(out / "result.h5")
    assert float(result.params["m"]) == pytest.approx(printed["params"]["m"], rel=1e-12)
    assert io.load(out / "result.h5").n == io.load(PLASTIC).n
    assert json.loads((out / "result.json").read_text())["status"] == "converged"
    assert "lambert+cook-torrance" in (out / "summary.txt").read_text()


def test_fit_default_output_goes_next_to_the_input(tmp_path, capsys):
    copy = tmp_path / "clay.h5"
    copy.write_bytes((ROOT / "data" / "synthetic" / "clay.h5").read_bytes())
    assert main(["fit", str(copy), "--model", "oren-nayar", "--quiet"]) == EXIT_OK
    assert capsys.readouterr().out == ""
    with h5py.File(tmp_path / "clay.brdffit" / "result.h5", "r") as f:
        assert "fits/oren-nayar" in f and "measurements" in f


def test_fit_with_fixed_parameter_and_solver(tmp_path, capsys):
    code = main(["fit", str(PLASTIC), "--model", "lambert+ggx", "--fixed", "f0=0.04", "--solver", "dogleg",
                 "--out", str(tmp_path / "o"), "--json"])
    printed = json.loads(capsys.readouterr().out)
    assert code == EXIT_OK and printed["params"]["f0"] == 0.04 and printed["stderr"]["f0"] == 0.0


def test_not_converged_fit_exits_1(tmp_path, capsys):
    code = main(["fit", str(PLASTIC), "--model", "lambert+cook-torrance", "--max-steps", "1", "--out",
                 str(tmp_path / "o"), "--json"])
    assert code == EXIT_NOT_CONVERGED
    assert json.loads(capsys.readouterr().out)["status"] == "max-steps"


@pytest.mark.parametrize("argv, message", [
    (["fit", "does-not-exist.h5"], "does-not-exist.h5"),
    (["fit", str(PLASTIC), "--model", "lambert+nonsense"], "unknown lobe 'nonsense'"),
    (["fit", str(PLASTIC), "--fixed", "f0"], "NAME=VALUE"),
    (["fit", str(PLASTIC), "--fixed", "f0=abc"], "not a number"),
    (["fit", str(PLASTIC), "--model", "lambert", "--fixed", "alpha=0.1"], "no parameter 'alpha'"),
    (["fit", str(PLASTIC), "--loss", "l1"], "invalid choice"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_input_exits_2_with_a_clear_message(argv, message, capsys, tmp_path):
    argv = argv + (["--out", str(tmp_path / "o")] if argv[0] == "fit" and len(argv) > 2 else [])
    assert main(argv) == EXIT_BAD_INPUT
    assert message in capsys.readouterr().err


def test_bad_file_content_exits_2_and_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("theta_i,phi_i,theta_o,phi_o,R\n10,0,20,180,0.3\n10,0,x,180,0.3\n")
    assert main(["fit", str(bad), "--model", "lambert", "--out", str(tmp_path / "o")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "bad.csv" in err and "'x'" in err


def test_info_reports_coverage_and_truth(capsys):
    assert main(["info", str(PLASTIC), "--json"]) == EXIT_OK
    info = json.loads(capsys.readouterr().out)
    m = io.load(PLASTIC)
    assert info["samples"] == m.n and info["channels"] == ["R", "G", "B"]
    assert info["theta_i_deg"] == pytest.approx([0.0, 70.0])
    assert info["missing_fraction"] == 0.0
    assert info["meta"]["truth"]["spec"] == "lambert+cook-torrance"
    assert main(["info", str(PLASTIC)]) == EXIT_OK
    assert "3072 samples x 3 channels" in capsys.readouterr().out


def test_models_and_version(capsys):
    assert main(["models"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "cook-torrance" in out and "alpha_x" in out
    assert main(["--version"]) == EXIT_OK
    assert "brdffit 0.1.0" in capsys.readouterr().out


def test_fit_lafortune_with_automatic_lobe_count(tmp_path, capsys):
    data = ROOT / "data" / "synthetic" / "lafortune-retro.h5"
    # --max-lobes 2 keeps the test short; choosing among 1..3 lobes is tested in test_select.py.
    code = main(["fit", str(data), "--model", "lambert+lafortune", "--lobes", "auto", "--max-lobes", "2",
                 "--loss", "sigma", "--out", str(tmp_path / "o"), "--json"])
    printed = json.loads(capsys.readouterr().out)
    assert code == EXIT_OK
    assert printed["model"] == "lambert+lafortune(lobes=2)"
    chosen = json.loads((tmp_path / "o" / "selection.json").read_text())
    assert chosen["chosen"] == "lambert+lafortune(lobes=2)" and len(chosen["table"]) == 2


def test_select_command_and_lobes_errors(tmp_path, capsys):
    clay = ROOT / "data" / "synthetic" / "clay.h5"
    assert main(["select", str(clay), "--candidates", "lambert;oren-nayar", "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["chosen"] == "oren-nayar"
    assert main(["fit", str(clay), "--model", "lambert", "--lobes", "2", "--out", str(tmp_path / "o")]) == \
        EXIT_BAD_INPUT
    assert "Lafortune" in capsys.readouterr().err
    assert main(["fit", str(clay), "--model", "lafortune", "--lobes", "two", "--out", str(tmp_path / "o")]) == \
        EXIT_BAD_INPUT
    assert "number of lobes" in capsys.readouterr().err


def test_synth_convert_and_posterior_commands(tmp_path, capsys):
    data = tmp_path / "ward.h5"
    assert main(["synth", "lambert+ward", "--param", "alpha=0.2", "--param", "ks=0.5,0.4,0.3", "--pattern",
                 "half-diff", "--n", "600", "--noise", "relative:0.01", "--seed", "3", "--out", str(data),
                 "--quiet"]) == EXIT_OK
    m = io.load(data)
    assert m.n == 600 and synth.truth_model(m).params["alpha"] == pytest.approx(0.2)
    # CSV round trip through convert keeps the numbers.
    assert main(["convert", str(data), str(tmp_path / "ward.csv"), "--quiet"]) == EXIT_OK
    np.testing.assert_allclose(io.load(tmp_path / "ward.csv").values, m.values, rtol=1e-12)
    # Fit with a posterior stored in result.h5, then continue the chain with the posterior command.
    out = tmp_path / "fit"
    code = main(["fit", str(data), "--model", "lambert+ward", "--loss", "sigma", "--posterior", "--walkers", "24",
                 "--steps", "150", "--out", str(out), "--json"])
    printed = json.loads(capsys.readouterr().out)
    assert code == EXIT_OK and printed["posterior"]["diagnostics"]["steps"] == 150
    assert printed["posterior"]["params"]["alpha"]["median"] == pytest.approx(0.2, rel=0.02)
    assert main(["posterior", str(out / "result.h5"), "--walkers", "24", "--steps", "200", "--json"]) == EXIT_OK
    resumed = json.loads(capsys.readouterr().out)
    assert resumed["diagnostics"]["steps"] == 200
    # A MERL tabulation needs a fit, not raw measurements.
    assert main(["convert", str(out / "result.h5"), str(tmp_path / "fit.binary"), "--quiet"]) == EXIT_OK
    assert io.read_merl(tmp_path / "fit.binary").data.shape == (3, 90, 90, 180)
    assert main(["convert", str(data), str(tmp_path / "raw.binary")]) == EXIT_BAD_INPUT
    assert "tabulating a model" in capsys.readouterr().err


def test_fit_model_auto_selects_among_the_standard_candidates(tmp_path, capsys, monkeypatch):
    # Three candidates keep the test short; the command passes brdffit.select.DEFAULT_CANDIDATES through.
    # (brdffit.select is the function; the module is reached through sys.modules.)
    monkeypatch.setattr(sys.modules["brdffit.select"], "DEFAULT_CANDIDATES", ("lambert", "oren-nayar", "lambert+ward"))
    clay = ROOT / "data" / "synthetic" / "clay.h5"  # Oren-Nayar truth
    assert main(["fit", str(clay), "--model", "auto", "--out", str(tmp_path / "o"), "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["model"] == "oren-nayar"
    assert json.loads((tmp_path / "o" / "selection.json").read_text())["chosen"] == "oren-nayar"


def test_export_command_writes_renderer_materials(tmp_path, capsys):
    out = tmp_path / "fit"
    assert main(["fit", str(PLASTIC), "--model", "lambert+ggx", "--out", str(out), "--quiet"]) == EXIT_OK
    xml_path = tmp_path / "plastic.xml"
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--out", str(xml_path), "--quiet"]) == EXIT_OK
    import xml.etree.ElementTree as ET

    bsdf = ET.fromstring(xml_path.read_text().split("-->")[-1].strip())
    assert bsdf.get("type") == "roughplastic"
    alpha = next(e for e in bsdf.iter() if e.get("name") == "alpha")
    fitted = FitResult.load(out / "result.h5")
    assert float(alpha.get("value")) == pytest.approx(float(fitted.params["alpha"]), rel=1e-6)
    assert main(["export", str(out / "result.h5"), "--to", "pbrt"]) == EXIT_OK
    assert "coateddiffuse" in capsys.readouterr().out
    ward = tmp_path / "ward"
    assert main(["fit", str(PLASTIC), "--model", "lambert+ward", "--out", str(ward), "--quiet"]) == EXIT_OK
    assert main(["export", str(ward / "result.h5"), "--to", "mitsuba"]) == EXIT_BAD_INPUT
    assert "ward" in capsys.readouterr().err


def test_render_command_previews_fit_and_data(tmp_path, capsys):
    import matplotlib.image as mpimg

    from brdffit import render

    out = tmp_path / "fit"
    assert main(["fit", str(PLASTIC), "--model", "lambert+cook-torrance", "--out", str(out), "--quiet"]) == EXIT_OK
    fit_png, data_png = tmp_path / "fit.png", tmp_path / "data.png"
    assert main(["render", str(out / "result.h5"), "--resolution", "48", "--out", str(fit_png), "--npy",
                 "--quiet"]) == EXIT_OK
    assert main(["render", str(PLASTIC), "--resolution", "48", "--out", str(data_png), "--quiet"]) == EXIT_OK
    fitted = FitResult.load(out / "result.h5")
    hdr = np.load(tmp_path / "fit.npy")
    np.testing.assert_allclose(hdr, render.render_sphere(fitted.model, resolution=48), rtol=1e-5, atol=1e-7)
    a, b = mpimg.imread(fit_png)[..., :3], mpimg.imread(data_png)[..., :3]
    assert a.shape == (48, 48, 3)
    # The fitted model and the interpolated measurement look alike (mean absolute 8-bit difference < 3 levels).
    assert np.mean(np.abs(a - b)) < 3 / 255
    assert main(["render", str(tmp_path / "missing.h5")]) == EXIT_BAD_INPUT


def test_fit_writes_a_report_and_the_report_command_rebuilds_it(tmp_path, capsys):
    out = tmp_path / "fit"
    assert main(["fit", str(PLASTIC), "--model", "lambert+cook-torrance", "--posterior", "--walkers", "24",
                 "--steps", "120", "--out", str(out), "--quiet"]) == EXIT_OK
    html = (out / "report.html").read_text()
    fitted = FitResult.load(out / "result.h5")
    assert f"{float(fitted.params['m']):.6g}" in html
    assert html.count("data:image/png;base64,") == 7  # five fit figures + corner + traces
    (out / "report.html").unlink()
    assert main(["report", str(out / "result.h5"), "--quiet"]) == EXIT_OK
    rebuilt = (out / "report.html").read_text()
    assert rebuilt.count("data:image/png;base64,") == 7
    assert "posterior median" in (out / "report.md").read_text().lower()
    bare = tmp_path / "bare"
    assert main(["fit", str(PLASTIC), "--model", "lambert+cook-torrance", "--no-report", "--out", str(bare),
                 "--quiet"]) == EXIT_OK
    assert not (bare / "report.html").exists()
