"""Real measurements (../shared/data): the gallery's stored fits reproduce its numbers, their Mitsuba exports render
what they state, the independent reference fitter (scripts/reference_fit.py) fitted afresh reproduces its numbers,
the default fit meets the accuracy target against it (default / reference <= 1 on every material, median <= 0.8),
and one default fit runs end to end through the CLI (docs/real-data.md).

The held-out errors are recomputed here from their definitions on docs/real-data.md, not with the gallery script's
code: the stored parameters, the shared file, the reference fitter and those definitions must give the page's
numbers.
"""

import functools
import json
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from brdffit import FitResult, io
from brdffit.cli import EXIT_OK, main

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
GALLERY = ROOT / "docs" / "real-data" / "gallery.json"
CONVERGED = ("converged", "converged-at-bound")

if not DATA.is_dir():
    pytest.skip("../shared/data is absent (a user's clone): the real measurements are not here",
                allow_module_level=True)

ROWS = json.loads(GALLERY.read_text())["rows"] if GALLERY.exists() else []

sys.path.insert(0, str(ROOT / "scripts"))
import reference_fit as ref  # noqa: E402  (the independent reference fitter: NumPy/SciPy only)

# Issue 36 point 4: the default fit's held-out error / the reference's <= 1.0 on every material, median <= 0.8.
TARGET_EACH, TARGET_MEDIAN = 1.0, 0.8


def _heldout_errors(f_model, f_data, cos_i) -> dict:
    """docs/real-data.md: ‖(f_m − f_d) cosθi‖ / ‖f_d cosθi‖, and RMS / median of |f_m − f_d| / f_d over f_d > 0."""
    ok = np.isfinite(f_data)
    c = cos_i[:, None]
    cosine = np.sqrt(np.sum(((f_model - f_data) * c)[ok] ** 2) / np.sum((f_data * c)[ok] ** 2))
    pos = ok & (f_data > 0)
    rel = np.abs(f_model[pos] - f_data[pos]) / f_data[pos]
    return {"cosine": cosine, "relative_rms": np.sqrt(np.mean(rel ** 2)), "relative_median": np.median(rel)}


def _heldout_data(row, measurements):
    """(θi, φi, θo, φo) and the measured values where the row's held-out error is taken."""
    h = row["heldout"]
    if h["kind"] == "rgl-lookup":  # pairs uniform in solid angle on θ <= max, the reference protocol's generator
        angles = ref.uniform_pairs(h["pairs"], np.random.default_rng(h["seed"]), h["max_theta_deg"])
        return angles, io.read_rgl(DATA / row["file"]).lookup(*angles)   # negative="clip", the default
    rows = _split(row, measurements)[0]
    return _at(measurements, rows), np.asarray(measurements.values, float)[rows]


def _split(row, measurements):
    """The held-out rows and the training rows of the selection's split (docs/real-data.md)."""
    h = row["heldout"]
    valid = np.flatnonzero(np.any(np.isfinite(measurements.values), axis=1))
    order = np.random.default_rng(h["seed"]).permutation(valid)
    held = int(round(h["fraction"] * len(order)))
    rows = np.sort(order[:held])
    assert len(rows) == h["rows"]
    return rows, np.sort(order[held:])


def _at(measurements, rows):
    return tuple(np.asarray(a, float)[rows] for a in (measurements.theta_i, measurements.phi_i,
                                                      measurements.theta_o, measurements.phi_o))


@functools.lru_cache(maxsize=None)
def _recomputed(name: str) -> dict:
    """A row's test errors recomputed: the stored default fit (or the ``train`` refit of a split material) and the
    reference fitted afresh to the training data (RGL-EPFL: the lookup at the protocol's training pairs; tables:
    the split's training rows, with the measurement's weights), both scored on the row's held-out pairs or rows."""
    row = next(r for r in ROWS if r["name"] == name)
    measurements = io.load(DATA / row["file"], **row["load"])
    angles, f_data = _heldout_data(row, measurements)
    path = ROOT / "docs" / row["fit_file"]
    scored = FitResult.load(path, row["heldout"]["fit"])
    if row["heldout"]["kind"] == "rgl-lookup":
        table = io.read_rgl(DATA / row["file"])
        train = ref.uniform_pairs(ref.TRAIN_PAIRS, np.random.default_rng(ref.TRAIN_SEED))
        fit = ref.fit_reference(*train, table.lookup(*train))
        protocol = ref.uniform_pairs(ref.TEST_PAIRS, np.random.default_rng(ref.TEST_SEED))
        f_protocol = table.lookup(*protocol)
        extra = {"protocol_default": ref.cosine_error(np.asarray(scored.predict(*protocol)), f_protocol, protocol[0]),
                 "protocol_reference": ref.cosine_error(fit.predict(*protocol), f_protocol, protocol[0])}
    else:
        train_rows = _split(row, measurements)[1]
        weights = None if measurements.weights is None else np.asarray(measurements.weights, float)[train_rows]
        fit = ref.fit_reference(*_at(measurements, train_rows), np.asarray(measurements.values, float)[train_rows],
                                weights)
        extra = {}
    cos_i = np.cos(angles[0])
    default = float(_heldout_errors(np.asarray(scored.predict(*angles)), f_data, cos_i)["cosine"])
    reference = float(_heldout_errors(fit.predict(*angles), f_data, cos_i)["cosine"])
    return {"model": fit.model, "default": default, "reference": reference, "ratio": default / reference, **extra}


def test_the_gallery_has_a_row_per_shared_material():
    assert ROWS, "docs/real-data/gallery.json is missing: run scripts/real_data_gallery.py"
    files = {r["file"] for r in ROWS}
    shared = {str(p.relative_to(DATA)) for p in DATA.rglob("*") if p.suffix in (".csv", ".bsdf", ".dat")}
    assert files == shared
    ptfe = io.load(DATA / "nist-ptfe" / "PTFE.data.csv", format="table", values="f_r11", channel_column="lambda",
                   columns={"theta_i": "thetai", "phi_i": "phi", "theta_o": "thetar", "phi_o": "phir"})
    assert sum(r["file"].startswith("nist-ptfe/") for r in ROWS) == len(ptfe.channels)  # one row per wavelength
    page = (ROOT / "docs" / "real-data.md").read_text()
    for r in ROWS:
        assert f"| [{r['name']}]" in page and (ROOT / "docs" / r["images"]["slices"]).exists()
        assert (ROOT / "docs" / r["images"]["spheres"]).exists()


@pytest.mark.parametrize("row", ROWS, ids=[r["name"] for r in ROWS])
def test_a_stored_fit_reproduces_its_gallery_numbers(row):
    path = ROOT / "docs" / row["fit_file"]
    result = FitResult.load(path, "default")
    assert result.spec == row["model"] and result.status == row["status"] and result.status in CONVERGED
    measurements = io.load(DATA / row["file"], **row["load"])
    angles, f_data = _heldout_data(row, measurements)
    scored = result if row["heldout"]["fit"] == "default" else FitResult.load(path, row["heldout"]["fit"])
    assert scored.status in CONVERGED
    got = _heldout_errors(scored.predict(*angles), f_data, np.cos(angles[0]))
    for key, value in got.items():
        assert value == pytest.approx(row["heldout"][key], rel=1e-6), key
    # The page shows the same numbers, as rounded there.
    page = (ROOT / "docs" / "real-data.md").read_text()
    line = next(s for s in page.splitlines() if s.startswith(f"| [{row['name']}]"))
    assert f"| {got['cosine']:.3g} |" in line
    assert f"| {got['relative_rms']:.3g} / {got['relative_median']:.3g} |" in line


@pytest.mark.parametrize("row", ROWS, ids=[r["name"] for r in ROWS])
def test_the_reference_fitted_afresh_reproduces_its_gallery_numbers(row):
    # Issue 36 point 4: beside each held-out error, the reference's on the same held-out pairs or rows, fitted
    # afresh here (NumPy/SciPy, about 1 s) to training data disjoint from them.
    stored = row["reference"]
    got = _recomputed(row["name"])
    assert got["model"] == stored["model"]
    assert got["default"] == pytest.approx(row["heldout"]["cosine"], rel=1e-6)
    assert got["default"] == pytest.approx(stored["default_test_error"], rel=1e-6)
    assert got["reference"] == pytest.approx(stored["test_error"], rel=1e-4)
    assert got["ratio"] == pytest.approx(stored["ratio"], rel=1e-4)
    if "protocol" in stored:   # the protocol figure: 2,000 pairs of default_rng(202)
        assert got["protocol_default"] == pytest.approx(stored["protocol"]["default"], rel=1e-6)
        assert got["protocol_reference"] == pytest.approx(stored["protocol"]["reference"], rel=1e-4)
    page = (ROOT / "docs" / "real-data.md").read_text()
    line = next(s for s in page.splitlines() if s.startswith(f"| [{row['name']}]"))
    assert f"| {row['heldout']['cosine']:.3g} | {stored['test_error']:.3g} | {stored['ratio']:.3f}" in line


def test_the_default_fit_is_within_the_target_of_the_reference():
    # On every shared material, from the recomputed errors (not the stored ones): the default fit's held-out error
    # <= 1.0x the reference's on each, and the median ratio <= 0.8. satin_rosaline is a tie (0.9999): both choose
    # lambert+ggx with Schlick's f0 and reach the same optimum of the same integral.
    assert ROWS
    ratios = {r["name"]: _recomputed(r["name"])["ratio"] for r in ROWS}
    over = {name: round(v, 4) for name, v in ratios.items() if not v <= TARGET_EACH}
    median = float(np.median(list(ratios.values())))
    assert not over, f"default / reference > {TARGET_EACH:g} on {over}"
    assert median <= TARGET_MEDIAN, f"median ratio {median:.3g} > {TARGET_MEDIAN:g}: {ratios}"


@pytest.mark.parametrize("row", ROWS, ids=[r["name"] for r in ROWS])
def test_a_stored_fits_mitsuba_export_loads_and_renders_within_its_stated_error(row):
    # What Mitsuba evaluates deviates from the fit by what the export's comments state for their uniform random
    # pairs (`random_pairs`: the near-peak pairs of the main number depend on the lobes written, not recomputed
    # here), to the 3 digits the comment gives.
    pytest.importorskip("mitsuba")
    from brdffit.export.mitsuba import evaluate_in_mitsuba
    from brdffit.export.terms import random_pairs
    from brdffit.models.model import evaluate_dirs

    text = (ROOT / "docs" / row["mitsuba"]["file"]).read_text()
    stated = re.search(r"cosine-weighted relative RMS error ([0-9.e+-]+)", text)
    assert stated and float(stated.group(1)) == pytest.approx(row["mitsuba"]["stated_rms"], rel=1e-2)
    alone = re.search(r"the uniform pairs alone: ([0-9.e+-]+)", text)
    uniform = float((alone or stated).group(1))
    model = FitResult.load(ROOT / "docs" / row["fit_file"], "default").model
    wi, wo = random_pairs()
    g = evaluate_in_mitsuba(text, wi, wo)           # loads it with mitsuba.load_string
    f = np.broadcast_to(np.asarray(evaluate_dirs(model, wi, wo)), g.shape)
    rms = np.sqrt(np.sum(((g - f) * wi[:, 2:3]) ** 2) / np.sum((f * wi[:, 2:3]) ** 2))
    assert rms == pytest.approx(uniform, rel=1e-2, abs=1e-6)    # Mitsuba works in float32


@pytest.mark.slow
def test_the_default_fit_of_a_real_file_converges_through_the_cli(tmp_path, capsys):
    # Issue 17 point 1 on the cheapest shared file (PTFE at 532 nm, 1,824 samples): `brdffit fit FILE` with no fit
    # options, only the table options that read the file. With an empty compilation cache and the report skipped
    # this took 46 s on the 2-core development machine at a load average of 3, 106 s at 10 (other jobs;
    # docs/real-data.md has the gallery's times); here it shares the session's compilation cache (conftest.py).
    out = tmp_path / "ptfe"
    t0 = time.perf_counter()
    code = main(["fit", str(DATA / "nist-ptfe" / "PTFE.data.csv"), "--columns",
                 "theta_i=thetai,phi_i=phi,theta_o=thetar,phi_o=phir", "--values", "f_r11", "--where", "lambda=0.532",
                 "--out", str(out), "--no-report", "--json"])
    seconds = time.perf_counter() - t0
    printed = json.loads(capsys.readouterr().out)
    assert code == EXIT_OK and printed["status"] in CONVERGED, printed["status"]
    selection = json.loads((out / "selection.json").read_text())
    chosen = next(r for r in selection["table"] if r["spec"] == selection["chosen"])
    assert chosen["status"] in CONVERGED and printed["model"] == selection["chosen"]
    assert all(r.get("verdict") for r in selection["table"])  # why each other candidate was not chosen
    print(f"brdffit fit PTFE 532 nm: {seconds:.1f} s, {printed['model']} {printed['status']}")
    assert seconds < 600


def test_a_layer_weight_is_not_put_on_a_bound_that_silences_its_shape():
    """Mitsuba's principled on NIST's PTFE at 633 nm, screened for `--for mitsuba`: the solver's ε-active set once put
    the clearcoat on 0 while its gloss sat at 0.84, where the gloss has no effect and the pair stopped (held-out
    error 0.0116, above the layered roughplastic's 0.0114, so the target chose that instead). The solver does not
    take a move onto a bound that silences another free scalar (`brdffit.fitting.marquardt.silenced`): the clearcoat
    reaches 0.68 with its gloss at 0, held-out 0.0079 (0.0080 before the ε-active set)."""
    import importlib.util

    from brdffit import select

    spec = importlib.util.spec_from_file_location("real_data_gallery", ROOT / "scripts" / "real_data_gallery.py")
    gallery = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gallery)
    entry = next(e for e in gallery.materials() if e["name"] == "ptfe-0.633um")
    selection = select(gallery.load_measurements(entry), ["lambert"], target="mitsuba")
    rows = {row["spec"]: row for row in selection.table}
    assert rows["principled"]["heldout_error"] < 0.0085, rows["principled"]
    assert selection.chosen == "principled"
    assert float(selection.result.params["clearcoat"]) > 0.5
