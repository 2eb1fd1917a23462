"""Spectral fits: a material of known per-band amplitudes and one shared roughness, written as a 31-band ASTM E1392
file and read back, is recovered within its standard errors; its report plots the amplitudes against wavelength."""

import numpy as np
import pytest

from brdffit import fit, io, models, synth
from brdffit.report import write_report

WAVELENGTHS = np.arange(400, 701, 10)


@pytest.fixture(scope="module")
def spectral(tmp_path_factory):
    """(truth, measurements read back from an ASTM file, the fit)."""
    rho = 0.2 + 0.5 * np.exp(-((WAVELENGTHS - 470) / 60.0) ** 2)
    truth = models.get("lambert+ggx", channels=len(WAVELENGTHS), rho_d=rho, ks=np.full(len(WAVELENGTHS), 0.3),
                       alpha=0.15)
    data = synth.generate(truth, pattern="gonio-grid", n=1500, noise="relative:0.01", seed=3)
    path = tmp_path_factory.mktemp("astm") / "paint.astm"
    io.save(data.replace(channels=[f"{w}nm" for w in WAVELENGTHS]), path)
    m = io.load(path)
    # The relative loss is the maximum-likelihood loss of this noise (an ASTM file has no σ column for "sigma").
    return truth, m, fit(m, "lambert+ggx", fixed={"f0": 0.04}, loss="relative")


def test_per_band_amplitudes_and_the_shared_roughness_are_recovered_within_their_stderr(spectral):
    truth, m, result = spectral
    assert m.meta["wavelengths_nm"] == [float(w) for w in WAVELENGTHS] and result.converged
    for name in ("rho_d", "ks"):
        z = (np.asarray(result.params[name]) - np.asarray(truth.params[name])) / np.asarray(result.stderr[name])
        # 1% noise: the errors are standard-normal-like; at most 2 of 31 bands beyond 3 stderr, none beyond 5.
        assert np.sum(np.abs(z) > 3) <= 2 and np.all(np.abs(z) < 5), (name, np.round(z, 2))
    assert abs(float(result.params["alpha"]) - 0.15) < 4 * float(result.stderr["alpha"])


def test_report_plots_the_spectra_only_for_spectral_data(spectral, tmp_path):
    _, m, result = spectral
    written = write_report(tmp_path / "spectral", m, result)
    figures = [str(p) for p in written["figures"]]
    assert any(p.endswith("spectra.png") for p in figures)
    assert "](spectra.png)" in open(written["md"], encoding="utf-8").read()
    plain = m.replace(meta={k: v for k, v in m.meta.items() if k != "wavelengths_nm"})
    assert not any(str(p).endswith("spectra.png") for p in write_report(tmp_path / "plain", plain, result)["figures"])


def test_report_spheres_and_renderer_exports_show_the_spectral_fit_in_srgb(spectral):
    from brdffit.colour import spectral_colour
    from brdffit.render import render_sphere
    from brdffit.report import figures
    from brdffit.report.assemble import _renderer_table

    _, m, result = spectral
    data, fitted, _ = figures.sphere_images(m, result, resolution=24)
    assert data.shape == fitted.shape == (24, 24, 3)
    bands = render_sphere(result.model, resolution=24)
    np.testing.assert_allclose(fitted, spectral_colour(WAVELENGTHS).linear_srgb(bands), atol=1e-14)
    _, rows = _renderer_table(result, [], list(m.meta["wavelengths_nm"]))
    mitsuba = next(row for row in rows if row[0] == "mitsuba")
    assert mitsuba[2] in ("exact", "approximate"), mitsuba


def test_a_spectral_fit_with_every_amplitude_fixed_has_no_spectra_figure_and_its_report_is_written(spectral, tmp_path):
    """Nothing to plot against wavelength: the report leaves the figure out (plotting no panel raised)."""
    import dataclasses

    _, m, result = spectral
    colours = [n for n in result.params if result.models[0].param_specs[n].colour]
    fixed = dataclasses.replace(result, fixed=sorted(set(result.fixed) | set(colours)))
    written = write_report(tmp_path / "fixed", m, fixed)
    assert not any(str(p).endswith("spectra.png") for p in written["figures"])
