"""The command line: the Quick start job end to end, info, models, and exit codes on bad input."""

import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from brdffit import FitResult, Measurements, io, models, synth
from brdffit.cli import EXIT_BAD_INPUT, EXIT_IMPLAUSIBLE, EXIT_NOT_CONVERGED, EXIT_OK, main

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "data" / "synthetic" / "plastic.h5"


@pytest.mark.slow
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


@pytest.mark.slow
def test_fit_with_fixed_parameter_and_solver(tmp_path, capsys):
    code = main(["fit", str(PLASTIC), "--model", "lambert+ggx", "--fixed", "f0=0.04", "--solver", "dogleg",
                 "--no-report", "--out", str(tmp_path / "o"), "--json"])
    printed = json.loads(capsys.readouterr().out)
    assert code == EXIT_OK and printed["params"]["f0"] == 0.04 and printed["stderr"]["f0"] == 0.0


def test_not_converged_fit_exits_1(tmp_path, capsys):
    code = main(["fit", str(PLASTIC), "--model", "lambert+cook-torrance", "--max-steps", "1", "--no-report", "--out",
                 str(tmp_path / "o"), "--json"])
    assert code == EXIT_NOT_CONVERGED
    assert json.loads(capsys.readouterr().out)["status"] == "max-steps"


def test_every_computing_command_turns_on_the_compilation_cache(tmp_path, monkeypatch):
    # `brdffit report`, `export` and `render` compiled every program anew in each process before they did.
    import jax

    out = tmp_path / "fit"
    assert main(["fit", str(ROOT / "data" / "synthetic" / "clay.h5"), "--model", "lambert", "--no-report", "--out",
                 str(out), "--quiet"]) == EXIT_OK
    result = str(out / "result.h5")
    before = jax.config.jax_compilation_cache_dir
    try:
        for k, argv in enumerate([["report", result], ["export", result, "--to", "mitsuba", "--out",
                                                        str(tmp_path / "m.xml")],
                                  ["render", result, "--resolution", "16", "--out", str(tmp_path / "r.png")]]):
            folder = tmp_path / f"cache-{k}"
            monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(folder))
            jax.config.update("jax_compilation_cache_dir", None)
            assert main(argv + ["--quiet"]) == EXIT_OK
            assert jax.config.jax_compilation_cache_dir == str(folder), argv[0]
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


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


@pytest.mark.slow
def test_fit_lafortune_with_automatic_lobe_count(tmp_path, capsys):
    data = ROOT / "data" / "synthetic" / "lafortune-retro.h5"
    # --max-lobes 2 keeps the test short; choosing among 1..3 lobes is tested in test_select.py.
    code = main(["fit", str(data), "--model", "lambert+lafortune", "--lobes", "auto", "--max-lobes", "2",
                 "--loss", "sigma", "--no-report", "--out", str(tmp_path / "o"), "--json"])
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


@pytest.mark.slow
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
                 "--steps", "150", "--no-report", "--out", str(out), "--json"])
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
    assert main(["fit", str(clay), "--model", "auto", "--no-report", "--out", str(tmp_path / "o"), "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["model"] == "oren-nayar"
    assert json.loads((tmp_path / "o" / "selection.json").read_text())["chosen"] == "oren-nayar"


@pytest.mark.slow
def test_export_command_writes_renderer_materials(tmp_path, capsys):
    out = tmp_path / "fit"
    assert main(["fit", str(PLASTIC), "--model", "lambert+ggx", "--no-report", "--out", str(out),
                 "--quiet"]) == EXIT_OK
    xml_path = tmp_path / "plastic.xml"
    # lambert+ggx on the plastic is IMPLAUSIBLE (ks·F ≈ 1.4: its Schlick f0 trades off against ks): a renderer
    # material of it is refused, with the reason on stderr and nothing written, unless forced
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--out", str(xml_path)]) == EXIT_IMPLAUSIBLE
    assert "IMPLAUSIBLE" in capsys.readouterr().err and not xml_path.exists()
    assert main(["export", str(out / "result.h5"), "--to", "json"]) == EXIT_OK  # brdffit's own JSON is no renderer
    capsys.readouterr()
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--out", str(xml_path), "--quiet",
                 "--force"]) == EXIT_OK
    import xml.etree.ElementTree as ET

    bsdf = ET.fromstring(xml_path.read_text().split("-->")[-1].strip())
    assert bsdf.get("type") == "blendbsdf"  # diffuse + GGX: the parts blended, each scaled (docs/export.md)
    alpha = next(e for e in bsdf.iter() if e.get("name") == "alpha")
    fitted = FitResult.load(out / "result.h5")
    assert float(alpha.get("value")) == pytest.approx(float(fitted.params["alpha"]), rel=1e-6)
    assert main(["export", str(out / "result.h5"), "--to", "pbrt", "--force"]) == EXIT_OK
    assert "\"mix\"" in capsys.readouterr().out
    ward = tmp_path / "ward"
    assert main(["fit", str(PLASTIC), "--model", "lambert+ward", "--no-report", "--out", str(ward),
                 "--quiet"]) == EXIT_OK
    assert main(["export", str(ward / "result.h5"), "--to", "mitsuba", "--force"]) == EXIT_BAD_INPUT
    assert "ward" in capsys.readouterr().err


def test_render_command_previews_fit_and_data(tmp_path, capsys):
    import matplotlib.image as mpimg

    from brdffit import render

    out = tmp_path / "fit"
    assert main(["fit", str(PLASTIC), "--model", "lambert+cook-torrance", "--no-report", "--out", str(out),
                 "--quiet"]) == EXIT_OK
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


@pytest.mark.slow
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


# ------------------------------------------------------------------------------------------- instrument tables
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
PTFE = DATA / "nist-ptfe" / "PTFE.data.csv"
PTFE_COLUMNS = ["--columns", "theta_i=thetai,phi_i=phi,theta_o=thetar,phi_o=phir", "--values", "f_r11"]
needs_ptfe = pytest.mark.skipif(not PTFE.exists(), reason=f"the NIST PTFE file is not at {PTFE} (../shared/data)")


def _info(argv, capsys) -> dict:
    assert main(["info", *argv, "--json"]) == EXIT_OK
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def ptfe_rows():
    """The PTFE file's rows parsed with the csv module (an independent reader): lambda, thetai, f_r11."""
    import csv

    with open(PTFE, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return np.array([[float(r["lambda"]), float(r["thetai"]), float(r["f_r11"])] for r in rows])


@needs_ptfe
def test_info_reads_the_ptfe_file_with_table_options(capsys, ptfe_rows):
    info = _info([str(PTFE), *PTFE_COLUMNS, "--where", "lambda=0.532"], capsys)
    at_532 = ptfe_rows[ptfe_rows[:, 0] == 0.532]
    assert info["samples"] == len(at_532) == 1824 and info["channels"] == ["f_r11"]
    # Six incidences: |thetai| of the file (the source at thetai <= 0, azimuth 0 -> 180 degrees).
    assert info["incidences"] == 6
    assert info["incidence_theta_i_deg"] == pytest.approx(sorted(set(np.abs(at_532[:, 1]).tolist())))
    assert info["incidence_theta_i_deg"] == pytest.approx([0.001, 15, 30, 45, 60, 75])
    assert info["value_range"] == [at_532[:, 2].min(), at_532[:, 2].max()]
    assert info["missing"] == 0 and info["sigma"] is False and info["weights_total"] is None
    assert info["format"] == "table"
    # The same as Python's read_table with the same options.
    m = io.load(PTFE, columns={"theta_i": "thetai", "phi_i": "phi", "theta_o": "thetar", "phi_o": "phir"},
                values="f_r11", where={"lambda": 0.532})
    assert info["theta_o_deg"] == [float(np.degrees(m.theta_o.min())), float(np.degrees(m.theta_o.max()))]
    # A comma list keeps any of the wavelengths; --channel-column makes one channel of each.
    both = _info([str(PTFE), *PTFE_COLUMNS, "--where", "lambda=0.351,1.064", "--channel-column", "lambda"], capsys)
    assert both["channels"] == ["lambda=0.351", "lambda=1.064"] and both["samples"] == 1824
    kept = ptfe_rows[np.isin(ptfe_rows[:, 0], [0.351, 1.064])]
    assert both["value_range"] == [kept[:, 2].min(), kept[:, 2].max()] and both["missing"] == 0
    assert main(["info", str(PTFE), *PTFE_COLUMNS, "--where", "lambda=0.532"]) == EXIT_OK
    text = capsys.readouterr().out
    assert "1824 samples x 1 channel (f_r11)" in text
    assert "incidences: 6 (theta_i 0.001, 15, 30, 45, 60, 75 deg)" in text
    assert "missing: 0 of 1824 values (0.00%)" in text


@needs_ptfe
def test_ptfe_without_column_options_says_how_to_name_them(capsys):
    assert main(["info", str(PTFE)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "PTFE.data.csv" in err and "no column 'theta_i'" in err and "--columns theta_i=NAME" in err


def _doc_examples() -> list[str]:
    """The commands of docs/cli.md's fenced blocks that read ../shared/data."""
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    blocks = text.split("```")[1::2]
    return [line.strip() for block in blocks for line in block.splitlines()
            if line.strip().startswith("brdffit ") and "../shared/data" in line]


def test_docs_list_the_table_options_as_declared():
    from brdffit.cli import table_options_doc

    assert table_options_doc() in (ROOT / "docs" / "cli.md").read_text(encoding="utf-8"), \
        "docs/cli.md's table of table options is stale: paste brdffit.cli.table_options_doc()"
    assert len(_doc_examples()) >= 4  # the PTFE examples are there to be run (next test)


@pytest.mark.slow
@needs_ptfe
def test_docs_cli_ptfe_examples_run_as_written(tmp_path, monkeypatch, capsys):
    import shlex

    # Run from a folder whose ../shared/data is the real one, so that the examples' outputs land in tmp_path.
    work = tmp_path / "project"
    work.mkdir()
    (tmp_path / "shared").symlink_to(DATA.parent, target_is_directory=True)
    monkeypatch.chdir(work)
    doc = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    for line in _doc_examples():
        argv = shlex.split(line.split("#")[0])[1:]
        # An example that wrote beside its input would write into ../shared/data: every one names its output.
        assert argv[0] in ("info", "convert") or "--out" in argv, f"docs/cli.md: {line!r} needs --out"
        assert main(argv) == EXIT_OK, f"docs/cli.md example failed: {line}\n{capsys.readouterr().err}"
        printed = capsys.readouterr().out
        if argv[0] == "info" and "--json" not in argv:
            assert printed in doc, f"docs/cli.md shows another output of {line!r}:\n{printed}"
        if argv[0] == "fit":
            result = json.loads(printed)
            assert result["status"] == "converged"
            assert result["params"]["rho_d"][0] == pytest.approx(0.987, abs=0.01)  # the value the page states
    assert io.load(work / "ptfe.h5").channels == ("lambda=0.351", "lambda=0.532", "lambda=0.633", "lambda=1.064")
    assert not any(p.name.endswith(".brdffit") for p in PTFE.parent.iterdir())


@pytest.fixture
def instrument_table(tmp_path):
    """A small instrument-style table: angles in radians under other names, two value columns with σ, a label
    column, a wavelength column, ';' separated, one negative value."""
    rng = np.random.default_rng(1)
    n = 40
    ti = np.repeat([0.1, 0.5], n // 2)
    to = rng.uniform(0, 1.2, n)
    po = rng.uniform(0, 6.2, n)
    lam = np.tile([0.5, 0.6], n // 2)
    a, b = rng.uniform(0.1, 0.5, n), rng.uniform(0.2, 0.9, n)
    a[3] = -0.01
    lines = ["wl;ti;pi;to;po;label;A;B;dA;dB"]
    lines += [f"{w!r};{t!r};0;{o!r};{p!r};s{k % 3};{x!r};{y!r};0.01;0.02"
              for k, (w, t, o, p, x, y) in enumerate(zip(*(c.tolist() for c in (lam, ti, to, po, a, b))))]
    path = tmp_path / "gonio.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_convert_with_table_options_gives_read_table_s_measurements(instrument_table, tmp_path, capsys):
    out = tmp_path / "g.h5"
    argv = ["convert", str(instrument_table), str(out), "--columns", "theta_i=ti,phi_i=pi,theta_o=to,phi_o=po",
            "--values", "A,B", "--sigma", "dA,dB", "--channels", "a,b", "--radians", "--delimiter", ";",
            "--negative", "missing", "--where", "wl=0.6", "--where", "label=s1", "--quiet"]
    assert main(argv) == EXIT_OK
    expected = io.read_table(instrument_table, columns={"theta_i": "ti", "phi_i": "pi", "theta_o": "to",
                                                        "phi_o": "po"},
                             values=["A", "B"], sigma=["dA", "dB"], channels=["a", "b"], degrees=False, delimiter=";",
                             negative="missing", where={"wl": 0.6, "label": "s1"})
    got = io.load(out)
    assert got.n == expected.n > 0 and got.channels == ("a", "b")
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values", "sigma"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
    # Radians: an angle read as degrees would differ by 180/pi.
    assert got.theta_i.max() == 0.5
    # --sigma none ignores σ columns; the default finds none here (they are not named sigma_<value>).
    info = _info([str(instrument_table), "--columns", "theta_i=ti,phi_i=pi,theta_o=to,phi_o=po", "--values", "A",
                  "--sigma", "none", "--radians", "--where", "wl=0.5"], capsys)
    assert info["sigma"] is False and info["samples"] == 20 and info["incidences"] == 2
    assert info["incidence_theta_i_deg"] == pytest.approx(np.degrees([0.1, 0.5]).tolist())


@pytest.mark.parametrize("extra, message, names", [
    (["--columns", "theta_i"], "argument --columns: 'theta_i': write KEY=COLUMN", "option"),
    (["--columns", "theta=ti"], "argument --columns: unknown key 'theta'", "option"),
    (["--columns", "theta_i=ti,theta_i=ti"], "argument --columns: 'theta_i' is given twice", "option"),
    (["--columns", "theta_i=tee,phi_i=pi,theta_o=to,phi_o=po"], "angle theta_i: no column 'tee'", "file"),
    (["--values", "C"], "values: no column 'C'", "file"),
    (["--where", "wl"], "argument --where: 'wl': write COLUMN=VALUE", "option"),
    (["--where", "wl=0.7"], "no row has wl = 0.7 (values in that column: 0.5, 0.6)", "file"),
    (["--where", "wl=0.5", "--where", "wl=0.6"], "--where wl: the column is filtered twice", "option"),
    (["--where", "nope=1"], "where: no column 'nope'", "file"),
    (["--delimiter", "ab"], "argument --delimiter: 'ab': give one character", "option"),
    (["--negative", "clip"], "argument --negative: 'clip'", "option"),
    (["--channel-column", "lam"], "channel_column: no column 'lam'", "file"),
])
def test_bad_table_options_exit_2_naming_option_file_or_column(extra, message, names, instrument_table, capsys):
    columns = [] if extra[0] == "--columns" else ["--columns", "theta_i=ti,phi_i=pi,theta_o=to,phi_o=po"]
    argv = ["info", str(instrument_table), *columns, "--radians", "--negative", "missing", *extra]
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert message in err
    if names == "file":
        assert f"{instrument_table}: " in err  # errors of reading start with the file


def test_table_options_for_a_non_table_file_are_a_usage_error(tmp_path, capsys):
    for command in (["info"], ["select", "--candidates", "lambert"], ["fit", "--model", "lambert", "--out",
                                                                       str(tmp_path / "o")],
                    ["render", "--out", str(tmp_path / "x.png")]):
        assert main([command[0], str(PLASTIC), *command[1:], "--where", "R=0.5", "--radians"]) == EXIT_BAD_INPUT
        err = capsys.readouterr().err
        assert "plastic.h5 is a hdf5 file; --where, --radians apply to instrument tables" in err, err
    assert main(["convert", str(PLASTIC), str(tmp_path / "p.csv"), "--values", "R"]) == EXIT_BAD_INPUT
    assert "--values applies to instrument tables" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (tmp_path / "x.png").exists()


def test_fit_refuses_an_output_folder_it_cannot_make_before_fitting(tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    assert main(["fit", str(PLASTIC), "--model", "lambert", "--out", str(blocker / "out")]) == EXIT_BAD_INPUT
    assert f"cannot write the output folder {blocker / 'out'}" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------- info
def test_info_shows_the_readers_meta_read_entries(tmp_path, capsys):
    rng = np.random.default_rng(0)
    n = 50
    theta_i = np.repeat(np.radians([10.0, 40.0, 40.0, 70.0, 0.0]), 10)
    phi_i = np.repeat(np.radians([0.0, 0.0, 90.0, 0.0, 123.0]), 10)  # 40 deg at two azimuths: two incidences
    values = rng.uniform(0.1, 0.4, (n, 2))
    values[[2, 7, 9], 0] = np.nan
    values[11, 1] = np.nan
    weights = rng.uniform(0.5, 1.5, n)
    read = {"negative values clipped to 0": 12, "missing (outgoing direction at or below the horizon)": 40,
            "scale": 0.5}
    m = Measurements(theta_i, phi_i, rng.uniform(0, 1.2, n), rng.uniform(0, 6, n), values, weights=weights,
                     channels=["R", "G"], meta={"format": "rgl", "description": "white paper", "read": read})
    path = tmp_path / "m.h5"
    io.save(m, path)
    assert io.load(path).meta["read"] == read  # HDF5 keeps the meta
    info = _info([str(path)], capsys)
    assert info["read"] == read and info["format"] == "rgl" and info["description"] == "white paper"
    assert info["missing"] == 4 and info["missing_fraction"] == pytest.approx(4 / 100)
    assert info["weights_total"] == pytest.approx(float(weights.sum()), rel=1e-12)
    assert info["incidences"] == 5 and info["incidence_theta_i_deg"] == pytest.approx([0, 10, 40, 40, 70])
    assert info["value_range"] == [float(np.nanmin(values)), float(np.nanmax(values))]
    assert main(["info", str(path)]) == EXIT_OK
    text = capsys.readouterr().out
    for line in ("50 samples x 2 channels (R, G)", "format: rgl", "description: white paper",
                 "incidences: 5 (theta_i 0, 10, 40, 40, 70 deg)", "missing: 4 of 100 values (4.00%)",
                 f"sigma: no, weights: yes, total {weights.sum():.6g}", "    negative values clipped to 0: 12",
                 "    missing (outgoing direction at or below the horizon): 40", "    scale: 0.5"):
        assert line in text, line


def test_info_on_a_merl_file(tmp_path, capsys):
    from brdffit.io import MerlTable

    data = np.broadcast_to(np.linspace(0.05, 0.3, 180), (3, 90, 90, 180)).copy()
    data[1, 0] = np.nan  # G missing in the first θh row
    path = tmp_path / "m.binary"
    io.write_merl(MerlTable(data), path)
    info = _info([str(path), "--sampling", "grid"], capsys)  # the cells themselves (the default draws pairs)
    m = io.load(path, sampling="grid")
    assert info["samples"] == m.n and info["format"] == "merl" and info["channels"] == ["R", "G", "B"]
    assert info["missing"] == int(np.isnan(m.values).sum()) > 0
    assert info["missing"] == int(np.isnan(m.values[:, 1]).sum())  # only G has holes
    # The cells above the horizon measure (2π)² sr² within 0.1 % (docs/formats.md); the θh row without G stays, as
    # R and B are present there.
    assert info["weights_total"] == pytest.approx(4 * np.pi ** 2, rel=1e-3)
    assert info["incidences"] > 12 and info["incidence_theta_i_deg"] is None
    assert info["value_range"] == pytest.approx([0.05, 0.3], rel=1e-12)
    assert main(["info", str(path), "--columns", "theta_i=a"]) == EXIT_BAD_INPUT
    assert "m.binary is a merl file; --columns applies to instrument tables" in capsys.readouterr().err


def test_info_and_table_options_load_no_jax(instrument_table):
    import subprocess

    script = ("import sys; from brdffit.cli import main; "
              f"assert main(['info', {str(PLASTIC)!r}]) == 0; "
              f"assert main(['info', {str(instrument_table)!r}, '--columns', 'theta_i=ti,phi_i=pi,theta_o=to,phi_o=po',"
              " '--values', 'A', '--radians', '--negative', 'missing']) == 0; "
              f"assert main(['convert', {str(PLASTIC)!r}, {str(instrument_table.with_suffix('.csv'))!r}, '--quiet'])"
              " == 0; "
              "print(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'optimistix', 'scipy')))")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout
    assert io.load(instrument_table.with_suffix(".csv")).n == io.load(PLASTIC).n


@pytest.mark.parametrize("kind, name, incidences", [
    ("alta", "alta-cea-retro/retro-gray-tape.dat", 3),  # 15, 30 and 60 degrees (../shared/data/README.md)
    # 8 incidences in the file (README), the last at theta_i = 90 degrees: no direction above the horizon there.
    ("rgl", "rgl-epfl/paper_white_rgb.bsdf", 7),
])
def test_info_on_the_other_readers_formats(kind, name, incidences, capsys):
    path = DATA / name
    if not path.exists():
        pytest.skip(f"{path} is absent (../shared/data)")
    if kind not in io.FORMATS:
        pytest.skip(f"brdffit.io does not read the {kind} format yet")
    grid = ["--sampling", "grid"] if kind == "rgl" else []  # the file's own incidences (the default draws pairs)
    info = _info([str(path), *grid], capsys)
    m = io.load(path, **({"sampling": "grid"} if grid else {}))
    assert info["format"] == kind and info["samples"] == m.n and info["incidences"] == incidences
    assert info["read"] == m.meta.get("read", {}) and info["read"]
    assert info["missing"] == int(np.isnan(m.values).sum())
    assert main(["info", str(path), *grid]) == EXIT_OK
    text = capsys.readouterr().out
    assert f"incidences: {incidences} (theta_i " in text
    for key in info["read"]:
        assert f"\n    {key}: " in text


def test_an_implausible_fit_warns_and_its_renderer_export_is_refused(tmp_path, capsys):
    """Values 20 times a material's: the fit exits 0 (it converged) but says on stderr that it is IMPLAUSIBLE, and
    `export` refuses a renderer material of it (exit 3, nothing written) unless --force."""
    truth = models.get("lambert+ggx", rho_d=[0.6, 0.5, 0.4], ks=[0.5, 0.5, 0.5], alpha=0.3, f0=0.04)
    data = synth.generate(truth, pattern="uniform", n=400, seed=2)
    path = tmp_path / "bright.csv"
    io.save(data.replace(values=data.values * 20.0, sigma=None), path)
    out = tmp_path / "bright.brdffit"
    assert main(["fit", str(path), "--model", "lambert+ggx", "--no-report", "--quiet", "--out", str(out)]) == EXIT_OK
    assert "is IMPLAUSIBLE" in capsys.readouterr().err
    xml = tmp_path / "bright.xml"
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--out", str(xml)]) == EXIT_IMPLAUSIBLE
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--force" in err and not xml.exists()
    assert main(["export", str(out / "result.h5"), "--to", "mitsuba", "--out", str(xml), "--force",
                 "--quiet"]) == EXIT_OK
    assert xml.is_file()


def _console_script(argv, *, at_exit: str | None = None, after: str = "", timeout: float = 120):
    """`brdffit.cli.run`, the console script's entry point, in a new process with ``argv``: ``at_exit`` an
    expression that an exit handler registered first prints, ``after`` code after the call (never reached)."""
    import subprocess

    lines = ["import atexit, gc, sys", "from brdffit import cli"]
    if at_exit is not None:
        lines.append(f"atexit.register(lambda: print({at_exit}))")
    lines += [f"sys.argv = ['brdffit'] + {[str(a) for a in argv]!r}", "cli.run()", after]
    return subprocess.run([sys.executable, "-c", "\n".join(lines)], capture_output=True, text=True, timeout=timeout)


def test_the_console_script_collects_garbage_less_often_and_a_callers_process_keeps_its_collector(tmp_path):
    """The console script's own process (`brdffit.cli.run`) collects with `COLLECTOR_THRESHOLDS` and has frozen the
    objects of the engine's imports once a command loaded it; `main` called in a caller's process changes neither
    (objects frozen there would never be collected)."""
    import gc

    from brdffit.cli import COLLECTOR_THRESHOLDS

    proc = _console_script(["synth", "lambert", "--n", "50", "--out", tmp_path / "s.h5", "--quiet"],
                           at_exit="'gc', gc.get_threshold(), gc.get_freeze_count()")
    assert proc.returncode == EXIT_OK, proc.stderr
    words = proc.stdout.split()
    assert words[0] == "gc" and proc.stdout.startswith(f"gc {COLLECTOR_THRESHOLDS}")
    assert int(words[-1]) > 10_000  # the modules of JAX and NumPy: far more objects than this
    threshold, frozen = gc.get_threshold(), gc.get_freeze_count()
    assert main(["synth", "lambert", "--n", "50", "--out", str(tmp_path / "t.h5"), "--quiet"]) == EXIT_OK
    assert gc.get_threshold() == threshold and gc.get_freeze_count() == frozen


def test_the_console_scripts_report_drawn_partly_by_its_worker_is_the_one_drawn_in_one_process(tmp_path):
    """`brdffit fit` in the console script's own process hands part of its report's figures to a
    `brdffit.report.worker.DrawingWorker`; they are byte for byte those that `brdffit report` draws in one process
    (`main`) from the same results file, and every figure is there."""
    from brdffit.report.assemble import HANDED

    data, fitted, again = tmp_path / "data.h5", tmp_path / "fit", tmp_path / "again"
    assert main(["synth", "lambert+ward", "--param", "alpha=0.2", "--noise", "relative:0.02", "--n", "600", "--out",
                 str(data), "--quiet"]) == EXIT_OK
    proc = _console_script(["fit", data, "--model", "lambert+ward", "--out", fitted, "--quiet"], timeout=300)
    assert proc.returncode == EXIT_OK, proc.stderr
    assert main(["report", str(fitted / "result.h5"), "--out", str(again), "--quiet"]) == EXIT_OK
    names = sorted(p.name for p in fitted.glob("*.png"))
    assert names == sorted(p.name for p in again.glob("*.png")) and {f"{n}.png" for n in HANDED} <= set(names)
    for name in names:
        assert (fitted / name).read_bytes() == (again / name).read_bytes(), name


@pytest.mark.parametrize("argv, code", [(["models"], EXIT_OK), (["fit", "no-such-file.h5"], EXIT_BAD_INPUT)])
def test_the_console_script_flushes_its_output_runs_the_exit_handlers_and_keeps_the_exit_code(argv, code):
    """`brdffit.cli.run` ends the process without Python's finalisation: what `main` printed to a pipe (block
    buffered, so lost without the flush) reaches the reader, an exit handler registered before it still runs
    (after the output), and the process exits with `main`'s code."""
    proc = _console_script(argv, at_exit="'exit handler ran'", after="print('not reached')")
    assert proc.returncode == code, proc.stderr
    assert proc.stdout.rstrip().endswith("exit handler ran") and "not reached" not in proc.stdout
    if code == EXIT_OK:
        assert proc.stdout.startswith("lambert: Lambert")
    else:
        assert "no-such-file.h5" in proc.stderr
