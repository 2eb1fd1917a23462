r"""The report's figures: one function per figure, each takes data objects and a path and writes one PNG.

What a figure shows is computed here (the model's values, renders and residuals); for the figures of every report
(slices, hemisphere, residuals, albedo, spheres) and the renderer's view, a ``*_drawing`` function returns it as a
`brdffit.report.drawing.Drawing`, which `brdffit.report.drawing` draws with matplotlib alone (in this process, or in
a helper process of its own: `brdffit.report.worker`), and the ``plot_*`` function does both; the posterior's
figures and the spectra are drawn here.
docs/report.md says how each figure is computed.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import to_half_diff
from ..properties import directional_albedo, judged_at_the_view, scan_albedo
from ..colour import ColourError, spectral_colour
from ..render import difference, render_sphere, tonemap
from .drawing import DPI, FIGSIZE, Drawing, drawing_style, new_figure, save

__all__ = [
    "drawing_style",
    "DPI",
    "FIGSIZE",
    "slice_angles",
    "plot_slices",
    "plot_hemisphere",
    "plot_residual_map",
    "plot_corner",
    "plot_traces",
    "plot_albedo",
    "plot_spheres",
]

# Largest number of parameters shown in the corner and trace plots (the first ones of the posterior).
MAX_POSTERIOR_PARAMS = 8

# Half-widths of the windows that select data for an in-plane slice: incidence within ±THETA_I_WINDOW of the
# slice's θi, outgoing direction within PLANE_WINDOW (angular distance) of the plane of incidence.
THETA_I_WINDOW = math.radians(5.0)
PLANE_WINDOW = math.radians(7.5)


# ------------------------------------------------------------------------------------------------ helpers
def _specs(fit_result):
    return fit_result.models[0].param_specs


def _unit_suffix(unit: str) -> str:
    return "" if unit in ("", "1") else f" ({unit})"


def param_axis_label(fit_result, label: str) -> str:
    """``label`` with its unit in brackets, e.g. ``"alpha"`` or ``"ks[0] (1/sr)"``.

    The posterior's noise scales ``noise_sigma[i]`` are in the units of the fit's loss residuals (σ-normalised
    for ``loss="sigma"``, hence about 1 when the stated σ are right).
    """
    name = label.split("[")[0]
    if name == "noise_sigma":
        return f"{label} ({fit_result.loss}-loss residual units)"
    try:
        return label + _unit_suffix(_specs(fit_result)[name].unit)
    except KeyError:
        return label


def _fit_models(fit_result) -> list:
    return [fit_result.model] if fit_result.model is not None else fit_result.models


def _at_the_view(fit_result) -> bool:
    """Whether the fit's albedo is the one at each view (`brdffit.properties.judged_at_the_view`)."""
    return any(judged_at_the_view(m) for m in _fit_models(fit_result))


def _fit_albedo(fit_result, theta) -> np.ndarray:
    """Directional albedo ``(len(theta), C)`` of the fitted model(s) (one model per channel when independent): at
    each incidence θi (`brdffit.properties.directional_albedo`), or for a model that is not reciprocal at each view
    θo (`brdffit.properties.scan_albedo` with ``view``)."""
    if _at_the_view(fit_result):
        parts = [scan_albedo(m, theta, np.zeros(1), view=True)[:, 0, :] for m in _fit_models(fit_result)]
    else:
        parts = [np.asarray(directional_albedo(m, theta)).reshape(len(theta), -1) for m in _fit_models(fit_result)]
    return np.concatenate(parts, axis=-1)


def _render_fit(fit_result, resolution: int) -> np.ndarray:
    return np.concatenate([render_sphere(m, resolution=resolution) for m in _fit_models(fit_result)], axis=-1)


def _as_srgb(hdr: np.ndarray, measurements) -> np.ndarray:
    """A render of spectral data or of their fit as linear sRGB (`brdffit.colour`: CIE 1931 XYZ under D65); other
    renders as they are."""
    wavelengths = spectral_axis(measurements, hdr.shape[-1]) if np.ndim(hdr) == 3 else None
    try:
        return hdr if wavelengths is None else spectral_colour(wavelengths).linear_srgb(hdr)
    except ColourError:  # bands the eye does not see (infrared, say): shown as the luminance of other data
        return hdr


def _display(hdr: np.ndarray, exposure: float) -> np.ndarray:
    """A displayable image: RGB for three channels (linear sRGB, `_as_srgb` for spectral renders), the luminance
    in grey otherwise."""
    if hdr.ndim == 3 and hdr.shape[2] not in (1, 3):
        hdr = hdr.mean(axis=-1)
    ldr = tonemap(hdr, exposure=exposure)
    return ldr[..., 0] if ldr.ndim == 3 and ldr.shape[2] == 1 else ldr


def slice_angles(measurements, count: int = 4) -> np.ndarray:
    """Up to ``count`` incidence angles (radians) for the in-plane slices.

    When the data hold a few distinct incidence angles (a goniometer), the ones with the most samples near the
    plane of incidence are taken; otherwise evenly spread angles between the 10th and 90th percentile of θi,
    rounded to whole degrees.
    """
    ti = np.asarray(measurements.theta_i)
    distinct = np.unique(np.round(np.degrees(ti), 1))
    if len(distinct) <= 3 * count:
        counts = [np.sum(np.abs(np.degrees(ti) - d) < 0.05) for d in distinct]
        order = np.argsort(counts)[::-1][:count]
        return np.radians(np.sort(distinct[order]))
    lo, hi = np.percentile(np.degrees(ti), [10, 90])
    return np.radians(np.round(np.linspace(lo, hi, count)))


# ------------------------------------------------------------------------------------------ 1. slices
def plot_slices(path, measurements, fit_result, posterior=None, theta_i=None) -> str:
    r"""In-plane slices: data near the plane of incidence and the fitted model, one panel per incidence angle.

    The outgoing angle is signed: θo > 0 on the mirror side (φo = φi + π), θo < 0 on the side of the light
    (φo = φi). Data are the samples with θi within `THETA_I_WINDOW` of the slice's angle and ωo within
    `PLANE_WINDOW` of the plane of incidence. With a posterior, its 68 % and 95 % credible bands of the model
    (`Posterior.predictive_band`) are shaded. f_r is on a log scale.

    Arguments:
        path: the PNG to write.
        measurements: the data.
        fit_result: the `FitResult`.
        posterior: an optional `Posterior` of the same fit.
        theta_i: incidence angles of the slices (radians, at most 4); default `slice_angles`.

    Returns:
        ``path`` as a string.
    """
    return slices_drawing(measurements, fit_result, posterior, theta_i)(path)


def slices_drawing(measurements, fit_result, posterior=None, theta_i=None) -> Drawing:
    """What `plot_slices` draws (arguments the same, but the path), as a `Drawing`."""
    angles = slice_angles(measurements) if theta_i is None else np.atleast_1d(np.asarray(theta_i, float))[:4]
    signed = np.radians(np.linspace(-89.0, 89.0, 357))
    curve_to = np.abs(signed)
    curve_po = np.where(signed >= 0, math.pi, 0.0)  # φi = 0: the mirror side is φo = π
    bands = None
    if posterior is not None and len(angles):
        ti_all = np.repeat(angles, len(signed))
        bands = posterior.predictive_band(ti_all, 0.0, np.tile(curve_to, len(angles)), np.tile(curve_po, len(angles)),
                                          n_draws=100)
    ti, pi_, to, po = (np.asarray(a) for a in (measurements.theta_i, measurements.phi_i, measurements.theta_o,
                                                measurements.phi_o))
    dphi = po - pi_
    # angular distance of ωo from the plane of incidence, and the side of the plane
    off_plane = np.arcsin(np.clip(np.abs(np.sin(to) * np.sin(dphi)), 0.0, 1.0))
    mirror_side = np.cos(dphi) < 0
    values = np.asarray(measurements.values)
    positive = values[np.isfinite(values) & (values > 0)]
    panels = []
    for k, a in enumerate(angles):
        near = (np.abs(ti - a) <= THETA_I_WINDOW) & (off_plane <= PLANE_WINDOW)
        rows = slice(k * len(signed), (k + 1) * len(signed))
        panels.append({"model": fit_result.predict(np.full_like(signed, a), 0.0, curve_to, curve_po),
                       "x": np.degrees(np.where(mirror_side, to, -to))[near], "y": values[near],
                       "count": int(near.sum()),
                       "bands": None if bands is None else {q: np.asarray(bands[q])[rows]
                                                            for q in (2.5, 16, 84, 97.5)}})
    ylim = (max(positive.min() * 0.5, 1e-6), positive.max() * 2.0) if positive.size else None
    return Drawing("draw_slices", dict(spec=fit_result.spec, channels=list(measurements.channels),
                                       angles=np.degrees(angles), signed=np.degrees(signed), panels=panels, ylim=ylim,
                                       windows=(math.degrees(THETA_I_WINDOW), math.degrees(PLANE_WINDOW))))


# --------------------------------------------------------------------------------------- 2. hemisphere
def plot_hemisphere(path, fit_result, theta_i: float = math.radians(30.0), channels=None,
                    resolution: int = 161) -> str:
    r"""The fitted model over the outgoing hemisphere for one incidence, f_r(ωi, ωo) cosθo, projected disc.

    Each point of the unit disc (x, y) = (sinθo cosφo, sinθo sinφo) is an outgoing direction (the orthographic
    projection of the hemisphere; the rim is the horizon). The light comes from φi = 0 (the right); the mirror
    direction is marked. One panel per channel (at most three), on a shared log colour scale.

    Arguments:
        path: the PNG to write.
        fit_result: the `FitResult`.
        theta_i: incidence angle (radians).
        channels: channel names (for the panel titles); default ``c0, c1, ...``.
        resolution: pixels across the disc.

    Returns:
        ``path`` as a string.
    """
    return hemisphere_drawing(fit_result, theta_i, channels, resolution)(path)


def hemisphere_drawing(fit_result, theta_i: float = math.radians(30.0), channels=None,
                       resolution: int = 161) -> Drawing:
    """What `plot_hemisphere` draws (arguments the same, but the path), as a `Drawing`."""
    u = np.linspace(-1.0, 1.0, resolution)
    x, y = np.meshgrid(u, u)
    r = np.hypot(x, y)
    inside = r < 1.0
    to = np.arcsin(np.clip(r, 0.0, 1.0))
    po = np.mod(np.arctan2(y, x), 2 * math.pi)
    f = fit_result.predict(np.full(inside.sum(), float(theta_i)), 0.0, to[inside], po[inside])
    n_ch = f.shape[1]
    names = list(channels) if channels is not None else [f"c{i}" for i in range(n_ch)]
    shown = list(range(min(n_ch, 3)))
    weighted = f * np.cos(to[inside])[:, None]
    pos = weighted[weighted > 0]
    vmax = float(pos.max()) if pos.size else 1.0
    vmin = max(vmax * 1e-2, float(pos.min()) if pos.size else vmax * 1e-2)
    grids = []
    for c in shown:
        grid = np.full(x.shape, np.nan)
        grid[inside] = np.maximum(weighted[:, c], vmin)
        grids.append(grid)
    return Drawing("draw_hemisphere", dict(spec=fit_result.spec, theta_i=float(theta_i), grids=grids,
                                           names=[names[c] for c in shown], vmin=vmin, vmax=vmax))


# ----------------------------------------------------------------------------------------- 3. residuals
def residual_map(measurements, fit_result, bins: int = 18):
    r"""Mean relative residual (model − data)/data per (θh, θd) bin and channel.

    Returns:
        ``(edges_h, edges_d, mean, count)``: bin edges in degrees (0-90), ``mean`` ``(C, bins, bins)`` indexed
        [channel, θd bin, θh bin] (NaN where a bin has no positive data), ``count`` of the same shape.
    """
    th, _, td, _ = to_half_diff(measurements.theta_i, measurements.phi_i, measurements.theta_o, measurements.phi_o,
                                xp=np)
    data = np.asarray(measurements.values)
    model = fit_result.predict(measurements.theta_i, measurements.phi_i, measurements.theta_o, measurements.phi_o)
    edges = np.linspace(0.0, 90.0, bins + 1)
    means, counts = [], []
    for c in range(data.shape[1]):
        ok = np.isfinite(data[:, c]) & (data[:, c] > 0)
        rel = (model[ok, c] - data[ok, c]) / data[ok, c]
        s, _, _ = np.histogram2d(np.degrees(td[ok]), np.degrees(th[ok]), bins=[edges, edges], weights=rel)
        n, _, _ = np.histogram2d(np.degrees(td[ok]), np.degrees(th[ok]), bins=[edges, edges])
        with np.errstate(invalid="ignore", divide="ignore"):
            means.append(np.where(n > 0, s / np.maximum(n, 1), np.nan))
        counts.append(n)
    return edges, edges, np.array(means), np.array(counts)


def plot_residual_map(path, measurements, fit_result, bins: int = 18) -> str:
    """Relative residual (model − data)/data averaged in (θh, θd) bins, one panel per channel (at most three).

    The colour scale is symmetric about 0 (blue: model too low, red: model too high) and spans the 98th
    percentile of |residual| over the bins; grey bins hold no data.

    Returns:
        ``path`` as a string.
    """
    return residual_drawing(measurements, fit_result, bins)(path)


def residual_drawing(measurements, fit_result, bins: int = 18) -> Drawing:
    """What `plot_residual_map` draws (arguments the same, but the path), as a `Drawing`."""
    eh, ed, mean, count = residual_map(measurements, fit_result, bins)
    return Drawing("draw_residuals", dict(spec=fit_result.spec, channels=list(measurements.channels), edges_h=eh,
                                          edges_d=ed, mean=mean, count=count, bins=bins))


# --------------------------------------------------------------------------------------- 4-5. posterior
def _posterior_columns(posterior) -> list[int]:
    return list(range(min(len(posterior.names), MAX_POSTERIOR_PARAMS)))


def plot_corner(path, posterior, fit_result=None) -> str:
    """Corner plot of the posterior: 2-d histograms of pairs below the diagonal, marginal histograms on it.

    The first `MAX_POSTERIOR_PARAMS` sampled parameters are shown. The least-squares value is drawn in red and
    the posterior median and 68 % interval as dashed lines on the marginals.

    Returns:
        ``path`` as a string.
    """
    fit_result = fit_result if fit_result is not None else posterior.fit
    cols = _posterior_columns(posterior)
    samples = np.asarray(posterior.samples)[:, cols]
    names = [posterior.names[i] for i in cols]
    labels = [param_axis_label(fit_result, n) if fit_result is not None else n for n in names]
    fits = [posterior.fit_values.get(n, np.nan) for n in names]
    k = len(cols)
    fig = new_figure("corner")
    axes = fig.subplots(k, k, squeeze=False)
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                ax.hist(samples[:, i], bins=30, color="0.4", histtype="stepfilled", alpha=0.6)
                q = np.percentile(samples[:, i], [16, 50, 84])
                for v in q:
                    ax.axvline(v, color="k", ls="--", lw=0.8)
                if np.isfinite(fits[i]):
                    ax.axvline(fits[i], color="tab:red", lw=1)
                ax.set_yticks([])
                ax.set_title(f"{names[i]} = {q[1]:.4g}", fontsize=7)
            else:
                ax.hist2d(samples[:, j], samples[:, i], bins=25, cmap="Greys")
                if np.isfinite(fits[i]) and np.isfinite(fits[j]):
                    ax.plot(fits[j], fits[i], "+", color="tab:red", ms=8)
            ax.tick_params(labelsize=6)
            for t in ax.get_xticklabels():
                t.set_rotation(45)
            if i == k - 1:
                ax.set_xlabel(labels[j], fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(labels[i], fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
    fig.suptitle(f"Posterior of {posterior.model_spec}: {len(samples)} samples; red = least-squares fit, "
                 "dashed = median and 68 % interval"
                 + (f" (first {k} of {len(posterior.names)} parameters)" if k < len(posterior.names) else ""),
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return save(fig, path)


def plot_traces(path, posterior, fit_result=None) -> str:
    """Trace plots: every walker's value against the step, one row per parameter, τ in each row's title.

    The discarded burn-in is shaded; the title gives the acceptance fraction and the integrated
    autocorrelation time τ of each parameter (emcee), in steps.

    Returns:
        ``path`` as a string.
    """
    fit_result = fit_result if fit_result is not None else posterior.fit
    cols = _posterior_columns(posterior)
    chain = np.asarray(posterior.chain)
    tau = list(posterior.diagnostics.get("tau", [np.nan] * chain.shape[2]))
    fig = new_figure("traces")
    axes = fig.subplots(len(cols), 1, squeeze=False, sharex=True)[:, 0]
    steps = np.arange(chain.shape[0])
    for ax, i in zip(axes, cols):
        ax.plot(steps, chain[:, :, i], color="k", alpha=0.25, lw=0.5)
        if posterior.burn > 0:
            ax.axvspan(0, posterior.burn, color="tab:orange", alpha=0.15, lw=0)
        name = posterior.names[i]
        ax.set_ylabel(param_axis_label(fit_result, name) if fit_result is not None else name, fontsize=8)
        ax.tick_params(labelsize=7)
        t = tau[i] if i < len(tau) else float("nan")
        ax.set_title(f"{name}: autocorrelation time τ = {t:.1f} steps", fontsize=8, loc="left", pad=2)
    axes[-1].set_xlabel("step")
    d = posterior.diagnostics
    fig.suptitle(f"Traces of {chain.shape[1]} walkers; acceptance fraction "
                 f"{d.get('acceptance_fraction', float('nan')):.2f}, "
                 f"max τ {d.get('tau_max', float('nan')):.1f} steps; shaded: burn-in ({posterior.burn} steps)",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return save(fig, path)


# ------------------------------------------------------------------------------------------- 6. albedo
def albedo_curve(fit_result, n: int = 46) -> np.ndarray:
    r"""Directional albedo a(θi) = ∫ f_r cosθo dωo of the fitted model(s), shape ``(n, C)``, at ``n`` angles θi
    from 0° to 89° (`brdffit.properties.directional_albedo`); for a model that is not reciprocal, its albedo at each
    view a(θo) = ∫ f_r cosθi dωi at ``n`` angles θo (`_fit_albedo`)."""
    return _fit_albedo(fit_result, np.radians(np.linspace(0.0, 89.0, n)))


def plot_albedo(path, fit_result, channels=None, n: int = 46, albedo: np.ndarray | None = None) -> str:
    r"""Directional albedo a(θi) = ∫ f_r cosθo dωo of the fitted model against θi, per channel (for a model that is
    not reciprocal, its albedo at each view against θo, the one its plausibility check judges).

    Computed with `albedo_curve` at ``n`` angles from 0° to 89°; the dashed line at 1 is the energy-conservation
    limit (a passive surface stays below it).

    Arguments:
        albedo: the curve `albedo_curve(fit_result)` when the caller has it already (its length sets ``n``).

    Returns:
        ``path`` as a string.
    """
    return albedo_drawing(fit_result, channels, n, albedo)(path)


def albedo_drawing(fit_result, channels=None, n: int = 46, albedo: np.ndarray | None = None) -> Drawing:
    """What `plot_albedo` draws (arguments the same, but the path), as a `Drawing`."""
    albedo = albedo_curve(fit_result, n) if albedo is None else np.asarray(albedo)
    names = list(channels) if channels is not None else [f"c{i}" for i in range(albedo.shape[1])]
    return Drawing("draw_albedo", dict(spec=fit_result.spec, albedo=albedo, names=names,
                                       at_the_view=_at_the_view(fit_result)))


def spectral_axis(measurements, channels: int):
    """The wavelengths (nm) of a spectral fit's channels, from ``meta["wavelengths_nm"]`` (ASTM E1392 bands) as
    `brdffit.colour.wavelengths_of` reads them, or None where the data have none or name another number of
    channels than the fit's (their bands are not the fit's channels).

    Raises:
        ColourError: one wavelength per channel, but not each a positive number once (`brdffit.colour.wavelengths_of`).
    """
    from ..colour import wavelengths_of

    found = (measurements.meta or {}).get("wavelengths_nm")
    if found is None or not isinstance(found, (list, tuple)) or len(found) != channels:
        return None
    return np.asarray(wavelengths_of(measurements.meta, channels), dtype=float)


def spectral_parameters(fit_result) -> list:
    """The names of a fit's free colour parameters: the panels of `plot_spectra` (none: no figure to draw)."""
    specs = fit_result.models[0].param_specs
    return [n for n in fit_result.params if specs[n].colour and n not in fit_result.fixed]


def plot_spectra(path, fit_result, wavelengths) -> str:
    """The colour parameters of a spectral fit against wavelength, each with its ±1 and ±2 standard-error bands
    (the stderr the summary states).

    Arguments:
        path: the PNG.
        fit_result: a fit whose colour parameters have one value per band.
        wavelengths: the bands' wavelengths, nm.

    Returns:
        ``path`` as a string.
    """
    specs = fit_result.models[0].param_specs
    names = spectral_parameters(fit_result)
    fig = new_figure("spectra")
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    for ax, name in zip(axes, names):
        value = np.asarray(fit_result.params[name], dtype=float)
        err = np.broadcast_to(np.asarray(fit_result.stderr.get(name, np.nan), dtype=float), value.shape)
        for k, alpha in ((2, 0.15), (1, 0.3)):
            ax.fill_between(wavelengths, value - k * err, value + k * err, color="C0", alpha=alpha, lw=0,
                            label=f"±{k} stderr")
        ax.plot(wavelengths, value, "o-", color="C0", ms=3, lw=1.2, label=name)
        ax.set_xlabel("wavelength (nm)")
        ax.set_ylabel(f"{name} ({specs[name].unit})")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"Fitted {fit_result.spec}: amplitudes per band ({len(wavelengths)} bands, "
                 f"{wavelengths.min():g}–{wavelengths.max():g} nm), stderr {fit_result.stderr_kind}", fontsize=11)
    return save(fig, path)


# ------------------------------------------------------------------------------------------ 7. spheres
def plot_renderer_view(path, measurements, free_result, target_result, target: str, errors: tuple,
                       resolution: int = 160) -> str:
    """What a renderer shows against what the data and the best free model show: sphere previews of the measurement
    (interpolated), the unconstrained fit and the fit for ``target``, each fit titled with its held-out error.

    Arguments:
        path: the PNG.
        measurements: the data.
        free_result, target_result: the unconstrained choice's fit and the target's.
        target: the renderer's name.
        errors: the held-out errors ``(free, target)`` (the selection's, on the same rows).
        resolution: pixels on a side.

    Returns:
        ``path`` as a string.
    """
    return renderer_drawing(measurements, free_result, target_result, target, errors, resolution)(path)


def renderer_drawing(measurements, free_result, target_result, target: str, errors: tuple,
                     resolution: int = 160) -> Drawing:
    """What `plot_renderer_view` draws (arguments the same, but the path), as a `Drawing`."""
    images = [_as_srgb(render_sphere(measurements, resolution=resolution), measurements),
              _as_srgb(_render_fit(free_result, resolution), measurements),
              _as_srgb(_render_fit(target_result, resolution), measurements)]
    titles = ["measurement (k-NN interpolated)", f"free: {free_result.spec}\nheld-out error {errors[0]:.4g}",
              f"for {target}: {target_result.spec}\nheld-out error {errors[1]:.4g} ({errors[1] / errors[0]:.2f}x)"]
    return Drawing("draw_renderer_view", dict(target=target, images=[_display(img, 1.0) for img in images],
                                              titles=titles, resolution=resolution))


def sphere_images(measurements, fit_result, resolution: int = 160):
    """HDR sphere renders of the measurement (interpolated) and of the fit, and their relative difference.

    Returns:
        ``(data_hdr, fit_hdr, diff)``; ``diff`` = `brdffit.render.difference` (fit against data). Spectral data
        (one wavelength per channel in ``meta["wavelengths_nm"]``) and their fit are rendered band by band and given
        as linear sRGB (`brdffit.colour`), so that ``diff`` compares luminance Y.
    """
    data = _as_srgb(render_sphere(measurements, resolution=resolution), measurements)
    fitted = _as_srgb(_render_fit(fit_result, resolution), measurements)
    return data, fitted, difference(fitted, data)


def plot_spheres(path, measurements, fit_result, resolution: int = 160) -> str:
    """Sphere previews side by side: measurement (interpolated) | fit | relative difference.

    Both renders use `brdffit.render.DEFAULT_LIGHTS` and the same Reinhard tone mapping and exposure; the
    difference is |Y_fit − Y_data| / max(Y_data, 1 % of its peak) on luminance, shown with a colour bar.

    Returns:
        ``path`` as a string.
    """
    return spheres_drawing(measurements, fit_result, resolution)(path)


def spheres_drawing(measurements, fit_result, resolution: int = 160) -> Drawing:
    """What `plot_spheres` draws (arguments the same, but the path), as a `Drawing`."""
    data, fitted, diff = sphere_images(measurements, fit_result, resolution)
    lit = diff[np.asarray(data).sum(axis=-1) > 0] if np.ndim(data) == 3 else diff
    return Drawing("draw_spheres", dict(spec=fit_result.spec, data=_display(data, 1.0), fitted=_display(fitted, 1.0),
                                        diff=diff, lit=np.asarray(lit), resolution=resolution))
