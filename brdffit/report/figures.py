r"""The report's figures: one function per figure, each takes data objects and a path and writes one PNG.

Every figure is drawn on a bare `matplotlib.figure.Figure` (no pyplot, no global backend: the Agg renderer is
used by ``savefig``), so that making a report never opens a window nor changes the caller's matplotlib state.
Every figure has a fixed size in pixels (`FIGSIZE` inches times `DPI`), a title, axis labels with units and a
legend or colour bar; angles are shown in degrees, f_r in 1/sr. Files are written atomically
(`brdffit.io._common.atomic_path`). docs/report.md says how each figure is computed.
"""

from __future__ import annotations

import math

import matplotlib
import numpy as np
from matplotlib.colors import LogNorm, TwoSlopeNorm
from matplotlib.ticker import LogFormatter, LogLocator
from matplotlib.figure import Figure

from ..geometry import to_half_diff
from ..io._common import atomic_path
from ..properties import directional_albedo, judged_at_the_view, scan_albedo
from ..colour import ColourError, spectral_colour
from ..render import difference, render_sphere, tonemap

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

# Resolution of every PNG and the size of each figure in inches: a figure of size (w, h) is w*DPI x h*DPI pixels.
DPI = 100
FIGSIZE = {
    "slices": (11.0, 8.0),
    "hemisphere": (12.0, 4.4),
    "residuals": (12.0, 4.4),
    "corner": (10.0, 10.0),
    "traces": (10.0, 12.0),
    "albedo": (7.0, 4.8),
    "spheres": (12.0, 4.4),
    "renderer": (12.0, 4.4),
    "spectra": (12.0, 4.4),
}

# The height of the panels' titles (matplotlib's axes.titley; 1 is the top of the axes), given so that matplotlib
# does not place them itself: it measures every tick label of the axes to clear them, at each draw (about a third
# of the in-plane slices figure's drawing), for figures that have no tick label above their axes (`drawing_style`).
TITLE_Y = 1.0

# zlib's level for the PNGs: 1 writes them several times faster than PIL's default (6), for files about a third
# larger; a report's figures are read once, on the same machine or attached to a message.
PNG_COMPRESSION = 1

# Each figure's subplot parameters (fractions of the figure), as matplotlib's tight_layout chose them on the shipped
# materials' reports (RGB, one to three lobes), the left margin widened for longer tick labels: tight_layout drew
# every figure once more to measure it, a sizeable share of a report's time. The posterior figures, whose grids grow
# with the parameters, keep tight_layout.
LAYOUT = {
    "slices": dict(left=0.08, right=0.986, bottom=0.133, top=0.889, wspace=0.17, hspace=0.3),
    "hemisphere": dict(left=0.073, right=0.898, bottom=0.059, top=0.846, wspace=0.373),
    "residuals": dict(left=0.052, right=0.868, bottom=0.133, top=0.803, wspace=0.22),
    "albedo": dict(left=0.1, right=0.966, bottom=0.122, top=0.879),
    "spheres": dict(left=0.013, right=0.94, bottom=0.034, top=0.897, wspace=0.042),
    "renderer": dict(left=0.013, right=0.987, bottom=0.034, top=0.86, wspace=0.042),
    "spectra": dict(left=0.07, right=0.98, bottom=0.14, top=0.86, wspace=0.28),
}

# Largest number of parameters shown in the corner and trace plots (the first ones of the posterior).
MAX_POSTERIOR_PARAMS = 8

# Half-widths of the windows that select data for an in-plane slice: incidence within ±THETA_I_WINDOW of the
# slice's θi, outgoing direction within PLANE_WINDOW (angular distance) of the plane of incidence.
THETA_I_WINDOW = math.radians(5.0)
PLANE_WINDOW = math.radians(7.5)

_RGB = {"r": "tab:red", "g": "tab:green", "b": "tab:blue", "red": "tab:red", "green": "tab:green",
        "blue": "tab:blue"}


# ------------------------------------------------------------------------------------------------ helpers
def drawing_style():
    """The settings the report draws its figures under (a context manager): the panels' titles at `TITLE_Y`."""
    return matplotlib.rc_context({"axes.titley": TITLE_Y})


def _new_figure(name: str) -> Figure:
    fig = Figure(figsize=FIGSIZE[name], dpi=DPI)
    if name in LAYOUT:
        fig.subplots_adjust(**LAYOUT[name])
    return fig


def _save(fig: Figure, path) -> str:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})
    return str(path)


class _PlainLogFormatter(LogFormatter):
    """matplotlib's `LogFormatter` (which ticks get a label) writing each value as ``%g``: "0.01", "2", "1e-05"."""

    def _num_to_string(self, x, vmin, vmax):
        return f"{x:g}"


def _plain_log_labels(axis) -> None:
    """Label a log-scaled axis in plain text ("0.01", "1e-05") rather than matplotlib's default mathtext
    ("10^{-2}" typeset by its TeX parser, `LogFormatterSciNotation`): the parser builds its grammar on first use,
    about 0.2 s of every report, for the same numbers. Its minor ticks are at 2, 3, 4 and 6 times each power of ten,
    the ones that matplotlib's formatter labels on an axis spanning 0.4 to 1 decade (`LogFormatter`'s
    ``minor_thresholds``; beyond a decade it labels none), rather than at all eight of 2-9: each tick is a set of
    artists built at every draw, and the four unlabelled ones cost the slices' figure about a seventh of its time.

    Arguments:
        axis: a matplotlib ``Axis`` on a log scale (set the scale first: setting it resets the formatters).
    """
    axis.set_minor_locator(LogLocator(base=10.0, subs=(2.0, 3.0, 4.0, 6.0)))
    axis.set_major_formatter(_PlainLogFormatter())
    axis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False))


def _channel_colours(channels) -> list:
    names = [str(c).lower() for c in channels]
    if len(names) <= 4 and all(n in _RGB for n in names):
        return [_RGB[n] for n in names]
    cycle = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:grey",
             "tab:olive", "tab:cyan"]
    return [cycle[i % len(cycle)] for i in range(len(names))]


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
    angles = slice_angles(measurements) if theta_i is None else np.atleast_1d(np.asarray(theta_i, float))[:4]
    colours = _channel_colours(measurements.channels)
    fig = _new_figure("slices")
    axes = fig.subplots(2, 2).ravel()
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
    for k, ax in enumerate(axes):
        if k >= len(angles):
            ax.set_visible(False)
            continue
        a = angles[k]
        model = fit_result.predict(np.full_like(signed, a), 0.0, curve_to, curve_po)
        near = (np.abs(ti - a) <= THETA_I_WINDOW) & (off_plane <= PLANE_WINDOW)
        x_data = np.degrees(np.where(mirror_side, to, -to))[near]
        for c, name in enumerate(measurements.channels):
            if bands is not None:
                rows = slice(k * len(signed), (k + 1) * len(signed))
                ax.fill_between(np.degrees(signed), bands[2.5][rows, c], bands[97.5][rows, c], color=colours[c],
                                alpha=0.12, lw=0, label="95 % band" if c == 0 else None)
                ax.fill_between(np.degrees(signed), bands[16][rows, c], bands[84][rows, c], color=colours[c],
                                alpha=0.25, lw=0, label="68 % band" if c == 0 else None)
            ax.plot(np.degrees(signed), model[:, c], color=colours[c], lw=1.4, label=f"fit {name}")
            y = values[near, c]
            ok = np.isfinite(y) & (y > 0)
            ax.plot(x_data[ok], y[ok], "o", ms=3.5, mfc="none", color=colours[c], alpha=0.8,
                    label=f"data {name}")
        ax.axvline(np.degrees(a), color="0.5", ls=":", lw=1, label="mirror direction")
        ax.axvline(0.0, color="0.8", lw=0.8)
        ax.set_yscale("log")
        _plain_log_labels(ax.yaxis)
        if positive.size:
            ax.set_ylim(max(positive.min() * 0.5, 1e-6), positive.max() * 2.0)
        ax.set_xlim(-90, 90)
        ax.set_title(f"θi = {np.degrees(a):.0f}°  ({int(near.sum())} samples within "
                     f"±{math.degrees(THETA_I_WINDOW):.0f}° "
                     f"of θi and {math.degrees(PLANE_WINDOW):.1f}° of the plane)", fontsize=9)
        ax.set_xlabel("signed θo (°): < 0 towards the light, > 0 mirror side")
        ax.set_ylabel("f_r (1/sr)")
        ax.grid(True, which="major", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.suptitle(f"In-plane BRDF slices: data vs fitted {fit_result.spec}"
                 + (" with posterior 68/95 % bands (shaded; may be thinner than the line)" if bands is not None
                    else ""), fontsize=11)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 9), fontsize=8, frameon=False)
    return _save(fig, path)


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
    norm = LogNorm(vmin=max(vmax * 1e-2, float(pos.min()) if pos.size else vmax * 1e-2), vmax=vmax)
    fig = _new_figure("hemisphere")
    axes = fig.subplots(1, len(shown), squeeze=False)[0]
    image = None
    for ax, c in zip(axes, shown):
        grid = np.full(x.shape, np.nan)
        grid[inside] = np.maximum(weighted[:, c], norm.vmin)
        image = ax.imshow(grid, origin="lower", extent=(-1, 1, -1, 1), norm=norm, cmap="inferno")
        t = np.linspace(0, 2 * math.pi, 200)
        for deg in (30, 60):
            ax.plot(np.sin(np.radians(deg)) * np.cos(t), np.sin(np.radians(deg)) * np.sin(t), color="0.6", lw=0.6)
            ax.text(np.sin(np.radians(deg)) * 0.72, np.sin(np.radians(deg)) * 0.72, f"θo={deg}°", color="white",
                    fontsize=7, ha="center", va="center", bbox=dict(fc="0.2", alpha=0.6, lw=0, pad=1))
        ax.plot([-np.sin(theta_i)], [0.0], "c+", ms=10, mew=1.5, label="mirror direction")
        ax.plot([np.sin(theta_i)], [0.0], "wx", ms=7, mew=1.5, label="light (ωi)")
        ax.set_title(f"channel {names[c]}", fontsize=10)
        ax.set_xlabel("sinθo cosφo")
        ax.set_ylabel("sinθo sinφo")
        ax.set_aspect("equal")
        ax.set_facecolor("0.85")
        ax.legend(fontsize=7, loc="lower left", facecolor="0.45", labelcolor="white")
    fig.suptitle(f"Fitted {fit_result.spec}: f_r cosθo over the outgoing hemisphere, "
                 f"θi = {np.degrees(theta_i):.0f}°, "
                 "φi = 0° (orthographic projection, rim = horizon)", fontsize=11)
    cax = fig.add_axes((0.93, 0.15, 0.015, 0.7))
    fig.colorbar(image, cax=cax, label="f_r cosθo (1/sr), log scale")
    _plain_log_labels(cax.yaxis)
    return _save(fig, path)


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
    eh, ed, mean, count = residual_map(measurements, fit_result, bins)
    shown = list(range(min(mean.shape[0], 3)))
    finite = np.abs(mean[np.isfinite(mean)])
    lim = float(np.percentile(finite, 98)) if finite.size else 1.0
    lim = lim if lim > 0 else 1e-3
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)
    fig = _new_figure("residuals")
    axes = fig.subplots(1, len(shown), squeeze=False)[0]
    image = None
    for ax, c in zip(axes, shown):
        image = ax.imshow(np.clip(mean[c], -lim, lim), origin="lower", extent=(eh[0], eh[-1], ed[0], ed[-1]),
                          norm=norm, cmap="RdBu_r", aspect="auto")
        ax.set_facecolor("0.8")
        n = count[c].sum()
        rms = float(np.sqrt(np.nanmean(mean[c] ** 2))) if np.isfinite(mean[c]).any() else float("nan")
        ax.set_title(f"channel {measurements.channels[c]}: {int(n)} samples, RMS of bin means {rms:.2g}",
                     fontsize=9)
        ax.set_xlabel("θh, half-vector angle (°)")
        ax.set_ylabel("θd, difference angle (°)")
    fig.suptitle(f"Relative residual (model − data)/data of {fit_result.spec}, mean per {90 / bins:.0f}° bin "
                 "(grey: no data)", fontsize=11)
    cax = fig.add_axes((0.89, 0.15, 0.015, 0.7))
    fig.colorbar(image, cax=cax, label="(model − data) / data")
    return _save(fig, path)


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
    fig = _new_figure("corner")
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
    return _save(fig, path)


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
    fig = _new_figure("traces")
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
    return _save(fig, path)


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
    albedo = albedo_curve(fit_result, n) if albedo is None else np.asarray(albedo)
    theta = np.radians(np.linspace(0.0, 89.0, len(albedo)))
    names = list(channels) if channels is not None else [f"c{i}" for i in range(albedo.shape[1])]
    colours = _channel_colours(names)
    fig = _new_figure("albedo")
    ax = fig.subplots()
    for c in range(albedo.shape[1]):
        ax.plot(np.degrees(theta), albedo[:, c], color=colours[c], lw=1.5, label=f"channel {names[c]}")
    ax.axhline(1.0, color="k", ls="--", lw=1, label="energy conservation (a = 1)")
    top = max(1.1, float(np.nanmax(albedo)) * 1.05)
    ax.set_ylim(0.0, top)
    ax.set_xlim(0, 90)
    if _at_the_view(fit_result):  # the albedo the plausibility check judges (`_fit_albedo`)
        ax.set_xlabel("θo, viewing angle (°)")
        ax.set_ylabel("albedo at the view a(θo) = ∫ f_r cosθi dωi (1)")
    else:
        ax.set_xlabel("θi, incidence angle (°)")
        ax.set_ylabel("directional albedo a(θi) (1)")
    ax.set_title(f"Directional albedo of the fitted {fit_result.spec}\nmax {float(np.nanmax(albedo)):.3f}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    return _save(fig, path)


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
    fig = _new_figure("spectra")
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
    return _save(fig, path)


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
    images = [(_as_srgb(render_sphere(measurements, resolution=resolution), measurements),
               "measurement (k-NN interpolated)"),
              (_as_srgb(_render_fit(free_result, resolution), measurements),
               f"free: {free_result.spec}\nheld-out error {errors[0]:.4g}"),
              (_as_srgb(_render_fit(target_result, resolution), measurements),
               f"for {target}: {target_result.spec}\nheld-out error {errors[1]:.4g} ({errors[1] / errors[0]:.2f}x)")]
    fig = _new_figure("renderer")
    for ax, (img, title) in zip(fig.subplots(1, 3), images):
        shown = _display(img, 1.0)
        ax.imshow(shown, cmap="gray" if shown.ndim == 2 else None, vmin=0, vmax=1)
        ax.set_title(title, fontsize=10)
        ax.set_xticks([]), ax.set_yticks([])
    fig.suptitle(f"The renderer's view ({resolution}×{resolution} px, key/fill/rim lights, Reinhard tone map): "
                 f"the data, the best free model and the best model {target} represents", fontsize=11)
    return _save(fig, path)


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
    data, fitted, diff = sphere_images(measurements, fit_result, resolution)
    fig = _new_figure("spheres")
    axes = fig.subplots(1, 3)
    for ax, img, title in ((axes[0], data, "measurement (k-NN interpolated)"), (axes[1], fitted, "fit")):
        shown = _display(img, 1.0)
        ax.imshow(shown, cmap="gray" if shown.ndim == 2 else None, vmin=0, vmax=1)
        ax.set_title(title, fontsize=10)
        ax.set_xticks([]), ax.set_yticks([])
    lit = diff[np.asarray(data).sum(axis=-1) > 0] if np.ndim(data) == 3 else diff
    vmax = float(np.percentile(lit, 99)) if lit.size else 1.0
    image = axes[2].imshow(diff, cmap="magma", vmin=0.0, vmax=max(vmax, 1e-3))
    axes[2].set_title(f"relative difference (median {float(np.median(lit)) if lit.size else 0:.2g})", fontsize=10)
    axes[2].set_xticks([]), axes[2].set_yticks([])
    fig.colorbar(image, ax=axes[2], fraction=0.046, pad=0.04, label="|Y_fit − Y_data| / Y_data")
    fig.suptitle(f"Sphere previews ({resolution}×{resolution} px, key/fill/rim lights, Reinhard tone map): "
                 f"data vs fitted {fit_result.spec}", fontsize=11)
    return _save(fig, path)
