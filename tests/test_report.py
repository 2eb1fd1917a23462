"""The fit report: figures, report.md and a self-contained report.html (brdffit.report)."""

import base64
import re

import numpy as np
import pytest

import brdffit
from brdffit.report import format_value, write_report
from brdffit.report import figures as F
from brdffit.report.drawing import plain_log_labels
from brdffit.report.worker import DrawingWorker

ALL_FIGURES = ("slices", "hemisphere", "residuals", "corner", "traces", "albedo", "spheres")
POSTERIOR_FIGURES = ("corner", "traces")


@pytest.fixture(scope="module")
def fitted():
    meas = brdffit.synth.generate("lambert+ward", pattern="half-diff", n=800, noise="relative:0.01", seed=0)
    result = brdffit.fit(meas, "lambert+ward", loss="sigma")
    post = brdffit.posterior(result, meas, nwalkers=24, nsteps=200, progress=False, seed=0)
    return meas, result, post


@pytest.fixture(scope="module")
def full_report(fitted, tmp_path_factory):
    meas, result, post = fitted
    out = tmp_path_factory.mktemp("report")
    paths = write_report(out, meas, result, posterior=post, run_info={"seed": 0, "command": "pytest"})
    return out, paths


def _png(path):
    import matplotlib.image

    return matplotlib.image.imread(path)


def test_returns_paths_of_written_files(full_report):
    out, paths = full_report
    assert paths["html"] == str(out / "report.html") and paths["md"] == str(out / "report.md")
    assert [p.rsplit("/", 1)[-1] for p in paths["figures"]] == [f"{n}.png" for n in ALL_FIGURES]
    # atomic writes leave no temporary files behind
    assert sorted(p.name for p in out.iterdir()) == sorted(["report.html", "report.md"]
                                                           + [f"{n}.png" for n in ALL_FIGURES])


def test_figures_have_their_size_and_are_not_blank(full_report):
    _, paths = full_report
    for path in paths["figures"]:
        name = path.rsplit("/", 1)[-1][:-4]
        image = _png(path)
        w, h = F.FIGSIZE[name]
        assert image.shape[:2] == (round(h * F.DPI), round(w * F.DPI)), name
        assert float(np.std(image[..., :3])) > 0.01, name


def test_html_is_self_contained_with_values_and_figures(fitted, full_report):
    _, result, post = fitted
    _, paths = full_report
    text = open(paths["html"], encoding="utf-8").read()
    assert text.startswith("<!DOCTYPE html>")
    assert format_value(result.params["alpha"]) in text
    assert format_value(post.summary["alpha"]["median"]) in text
    uris = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(uris) == len(ALL_FIGURES)
    for uri, path in zip(uris, paths["figures"]):  # the embedded images are the PNGs, byte for byte
        assert base64.b64decode(uri) == open(path, "rb").read()
    # no external references: every src/href is a data URI, no stylesheet or script is linked
    for ref in re.findall(r'(?:src|href)="([^"]*)"', text):
        assert ref.startswith("data:"), ref
    assert "<link" not in text and "<script" not in text and ".png\"" not in text


def test_markdown_has_parameter_table_and_run_info(fitted, full_report):
    meas, result, post = fitted
    _, paths = full_report
    md = open(paths["md"], encoding="utf-8").read()
    rows = [line for line in md.splitlines() if line.startswith("| alpha |")]
    assert len(rows) == 1
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    assert cells[1] == format_value(result.params["alpha"])
    # the default standard error, then the other kind (loss="sigma" with the σ the noise used: the residuals
    # choose the stated σ, so Laplace, then the sandwich)
    assert result.noise_model.name == "sigma" and result.stderr_kind == "laplace"
    assert "± stderr (Laplace) | ± sandwich" in md
    assert cells[2] == format_value(result.stderr["alpha"], 3)
    assert cells[3] == format_value(result.stderr_robust["alpha"], 3)
    assert cells[4] == format_value(post.summary["alpha"]["median"])
    s = post.summary["alpha"]
    assert cells[5] == f"[{format_value(s['q16'])}, {format_value(s['q84'])}]"
    assert cells[6] == f"[{format_value(s['q2.5'])}, {format_value(s['q97.5'])}]"
    # every parameter of the model has a row, and the noise scales of the posterior too
    for label in post.names:
        assert f"| {label} |" in md
    for name in ("## Noise model", "## Plausibility", "## Fit metrics", "rmse_rel", "## Warnings",
                 "## Run information", "brdffit: ", "jax: ",
                 "python: ", "seed: 0", "command: pytest", "date: "):
        assert name in md
    # the chain is short, so the posterior warns, and the warning is in the report
    assert any(w in md for w in post.warnings)
    for name in ALL_FIGURES:
        assert f"({name}.png)" in md


def test_without_posterior_the_posterior_figures_are_absent(fitted, tmp_path):
    meas, result, _ = fitted
    paths = write_report(tmp_path, meas, result)
    names = [p.rsplit("/", 1)[-1][:-4] for p in paths["figures"]]
    assert names == [n for n in ALL_FIGURES if n not in POSTERIOR_FIGURES]
    assert not (tmp_path / "corner.png").exists() and not (tmp_path / "traces.png").exists()
    text = open(paths["html"], encoding="utf-8").read()
    assert text.count("data:image/png;base64,") == len(names)
    assert format_value(result.params["alpha"]) in text
    md = open(paths["md"], encoding="utf-8").read()
    assert "posterior median" not in md and "| alpha |" in md


def test_residual_map_of_the_truth_is_the_noise(fitted):
    meas, result, _ = fitted
    _, _, mean, count = F.residual_map(meas, result)
    assert count.sum() == np.isfinite(meas.values).sum()
    assert np.nanmax(np.abs(mean)) < 0.05  # 1 % relative noise, a few samples per bin


def test_format_value():
    assert format_value(0.123456789) == "0.123457"
    assert format_value(float("nan")) == "–" and format_value(None) == "–"
    assert format_value(float("inf")) == "inf"


# ------------------------------------------------------------------------------------------------ renderer exports
def _section_rows(md):
    """The rows of the report's renderer-exports table, as lists of cells."""
    section = md.split("## Renderer exports", 1)[1].split("\n## ", 1)[0]
    return [[c.strip() for c in line.strip("|").split("|")] for line in section.splitlines()
            if line.startswith("| ") and not line.startswith("| renderer |")]


def test_report_says_which_renderers_have_no_equivalent(full_report):
    # lambert+ward: neither renderer has a Ward lobe; the report says so with the export's own reason.
    _, paths = full_report
    rows = _section_rows(open(paths["md"], encoding="utf-8").read())
    # Every registered renderer has a row: none has a Ward lobe (glTF, Blender, MaterialX and OpenPBR write one
    # model of their own, which `--for` fits).
    assert [(r[0], r[1], r[2], r[3], r[4]) for r in rows] == [
        (to, "direct", "no equivalent", "–", "–")
        for to in ("mitsuba", "pbrt", "gltf", "blender", "materialx", "openpbr")]
    assert all("lobe 'ward'" in r[5] and "fit=True (--fit)" in r[5] for r in rows[:2])
    assert all("lambert+ward" in r[5] and "--for" in r[5] and "(--fit)" in r[5] for r in rows[2:])
    html = open(paths["html"], encoding="utf-8").read()
    assert "<h2>Renderer exports</h2>" in html and "no equivalent" in html


@pytest.mark.parametrize("spec, params, verdicts", [
    ("lambert", {"rho_d": [0.5, 0.3, 0.2]}, {"mitsuba": "exact", "pbrt": "exact"}),
    # docs/export.md: GGX with conductor Fresnel is Mitsuba's roughconductor exactly; pbrt-v4's conductor shadows
    # with the height-correlated Smith term and has no amplitude, an approximation.
    ("lambert+ggx(fresnel=conductor)", {"rho_d": 0.3, "ks": 0.5, "alpha": 0.2},
     {"mitsuba": "exact", "pbrt": "approximate"}),
    # The glTF model: the glTF file writes it exactly, the MaterialX document with its stated OpenPBR approximation.
    ("gltf", {"base_color": [0.5, 0.3, 0.2], "roughness": 0.4}, {"gltf": "exact", "materialx": "approximate"}),
])
def test_report_states_the_direct_mappings_measured_deviation(spec, params, verdicts):
    from brdffit.export import export_details
    from brdffit.models import get
    from brdffit.report.assemble import _renderer_table

    model = get(spec, **params)
    headers, rows = _renderer_table(model, [])
    assert headers[3:5] == ["cosine-weighted relative RMS", "largest relative error"]
    mapped = [r for r in rows if r[2] != "no equivalent"]
    assert [(r[0], r[1], r[2]) for r in mapped] == [(to, "direct", v) for to, v in verdicts.items()]
    for row in mapped:
        details = export_details(model, row[0])
        # the numbers the export's comments state, to their printed digits
        assert row[3] == f"{details.deviation.rms:.3g}" and row[4] == f"{details.deviation.max_rel:.3g}"
        assert f"relative RMS error {row[3]}, largest relative error {row[4]} " in details.text
        assert row[5] == ("; ".join(details.notes) or "–")
        assert (row[2] == "exact") == details.exact == (details.deviation.rms <= 1e-6 and not details.notes)


def test_log_axes_are_labelled_in_plain_text():
    """The report's log axes carry "%g" labels ("0.001", "10"), not mathtext: no label holds a "$" (matplotlib's
    TeX parser, built on first use, is never needed), and the decades over three orders read as numbers."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure()
    FigureCanvasAgg(fig)  # draws for real, setting the tick labels
    ax = fig.subplots()
    ax.plot([1e-3, 10.0], [1e-3, 10.0])
    ax.set_yscale("log")
    ax.set_ylim(1e-3, 10.0)
    plain_log_labels(ax.yaxis)

    def shown(minor):  # the labels of the ticks inside the view
        fig.canvas.draw()
        low, high = ax.get_ylim()
        ticks = [t for t in (ax.yaxis.get_minor_ticks() if minor else ax.yaxis.get_major_ticks())
                 if low <= t.get_loc() <= high]
        return [t.label1.get_text() for t in ticks if t.label1.get_text()]

    assert shown(minor=False) == ["0.001", "0.01", "0.1", "1", "10"]
    ax.set_ylim(0.2, 0.9)  # less than a decade: the minor ticks are labelled instead
    minor = shown(minor=True)
    assert minor == ["0.2", "0.3", "0.4", "0.6"], minor  # matplotlib's choice of minor labels, in plain text


def test_albedo_of_a_layered_renderer_model_is_its_albedo_at_each_view():
    """A report's albedo curve and its warnings use the albedo the plausibility check judges: for the openpbr model
    (not reciprocal) the albedo at each view, which its layering keeps within 1 for a bright plastic, where the
    albedo of grazing light passes 1 (1.2 at 89°)."""
    from brdffit import models, synth
    from brdffit.properties import directional_albedo
    from brdffit.report import figures
    from brdffit.report.assemble import _albedo_warnings

    truth = models.get("openpbr", base_color=[0.9, 0.85, 0.8], specular_roughness=0.4, specular_ior=1.5)
    result = brdffit.fit(synth.generate(truth, pattern="half-diff", n=600, seed=2), "openpbr")
    curve = figures.albedo_curve(result)
    assert curve.max() <= 1.0 and not _albedo_warnings(curve, ["R", "G", "B"])
    assert np.asarray(directional_albedo(result.model, np.radians([89.0]))).max() > 1.1


def test_a_drawing_worker_writes_the_same_figures_as_this_process_and_stands_in_for_itself(fitted, tmp_path):
    """A `DrawingWorker` (a process of its own, matplotlib without JAX) writes byte for byte the PNGs that this
    process writes from the same `Drawing`s, given one at a time or all at once (the caller then draws those the
    worker has not taken); where its process is gone, `finish` draws them here."""
    meas, result, _ = fitted
    drawings = {"slices": F.slices_drawing(meas, result), "residuals": F.residual_drawing(meas, result),
                "albedo": F.albedo_drawing(result, channels=meas.channels),
                "spheres": F.spheres_drawing(meas, result), "hemisphere": F.hemisphere_drawing(result)}
    here, there, fallback = (tmp_path / name for name in ("here", "there", "fallback"))
    for folder in (here, there, fallback):
        folder.mkdir()
    for name, drawing in drawings.items():
        drawing(here / f"{name}.png")
    with DrawingWorker.start() as worker:
        for name, drawing in drawings.items():  # one at a time: the worker is given each (the caller takes none)
            worker.send(there / f"{name}.png", drawing)
            worker.finish()
        assert worker.given == len(drawings)
    with DrawingWorker.start() as shared:  # all at once: the worker is given the first, the caller takes the others
        for name, drawing in drawings.items():
            shared.send(tmp_path / f"shared-{name}.png", drawing)
        shared.finish()
        assert shared.given >= 1
    with DrawingWorker.start() as gone:
        gone._process.kill()
        gone._process.wait()
        for name, drawing in drawings.items():
            gone.send(fallback / f"{name}.png", drawing)
        gone.finish()
    for name in drawings:
        expected = (here / f"{name}.png").read_bytes()
        assert (there / f"{name}.png").read_bytes() == expected, name
        assert (tmp_path / f"shared-{name}.png").read_bytes() == expected, name
        assert (fallback / f"{name}.png").read_bytes() == expected, name


def test_the_drawing_worker_loads_matplotlib_not_jax():
    """The worker's process imports the drawing module alone: not JAX, whose import would double its start."""
    import subprocess
    import sys

    code = ("import sys\n"
            "import brdffit.report.drawing\n"
            "print('jax' in sys.modules, 'matplotlib' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.split() == ["False", "True"], proc.stderr
