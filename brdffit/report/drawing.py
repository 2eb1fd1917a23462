r"""How the report's figures are drawn from their arrays: matplotlib and NumPy only.

`brdffit.report.figures` computes what each figure shows (the model's values, renders, residuals: JAX's work) and
gives it here as a `Drawing`, the name of a drawing function of this module and its arguments (arrays, strings and
numbers, which pickle small). Drawing one is matplotlib's work alone, so that a process that has not loaded JAX can
do it (`brdffit.report.worker`).

Every figure is drawn on a bare `matplotlib.figure.Figure` (no pyplot, no global backend: the Agg renderer is
used by ``savefig``), so that making a report never opens a window nor changes the caller's matplotlib state.
Every figure has a fixed size in pixels (`FIGSIZE` inches times `DPI`), a title, axis labels with units and a
legend or colour bar; angles are shown in degrees, f_r in 1/sr. Files are written atomically
(`brdffit.io._common.atomic_path`).
"""

from __future__ import annotations

from typing import NamedTuple

import matplotlib
import numpy as np
from matplotlib.colors import LogNorm, TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter, LogLocator

from ..io._common import atomic_path

__all__ = ["Drawing", "drawing_style", "DPI", "FIGSIZE", "draw_slices", "draw_hemisphere", "draw_residuals",
           "draw_albedo", "draw_spheres", "draw_renderer_view"]

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

_RGB = {"r": "tab:red", "g": "tab:green", "b": "tab:blue", "red": "tab:red", "green": "tab:green",
        "blue": "tab:blue"}


class Drawing(NamedTuple):
    """A figure ready to draw: the name of its drawing function in this module and that function's arguments
    besides the path (arrays, strings and numbers). ``drawing(path)`` draws it under `drawing_style` and returns the
    path as a string."""

    draw: str
    arguments: dict

    def __call__(self, path) -> str:
        with drawing_style():
            return globals()[self.draw](path, **self.arguments)


# ------------------------------------------------------------------------------------------------ helpers
def drawing_style():
    """The settings the report draws its figures under (a context manager): the panels' titles at `TITLE_Y`."""
    return matplotlib.rc_context({"axes.titley": TITLE_Y})


def new_figure(name: str) -> Figure:
    """A bare figure of `FIGSIZE` ``name`` at `DPI`, with its `LAYOUT` where it has one."""
    fig = Figure(figsize=FIGSIZE[name], dpi=DPI)
    if name in LAYOUT:
        fig.subplots_adjust(**LAYOUT[name])
    return fig


def save(fig: Figure, path) -> str:
    """Write ``fig`` as a PNG at ``path`` atomically; returns the path as a string."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})
    return str(path)


class _PlainLogFormatter(LogFormatter):
    """matplotlib's `LogFormatter` (which ticks get a label) writing each value as ``%g``: "0.01", "2", "1e-05"."""

    def _num_to_string(self, x, vmin, vmax):
        return f"{x:g}"


def plain_log_labels(axis) -> None:
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


def channel_colours(channels) -> list:
    """A line colour per channel: red, green and blue for channels so named, else matplotlib's tab cycle."""
    names = [str(c).lower() for c in channels]
    if len(names) <= 4 and all(n in _RGB for n in names):
        return [_RGB[n] for n in names]
    cycle = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:grey",
             "tab:olive", "tab:cyan"]
    return [cycle[i % len(cycle)] for i in range(len(names))]


# ------------------------------------------------------------------------------------------------ figures
def draw_slices(path, *, spec: str, channels, angles, signed, panels, ylim, windows) -> str:
    """The in-plane slices (`brdffit.report.figures.plot_slices`).

    Arguments:
        spec: the fitted model's spec (the title).
        channels: the channel names.
        angles: each panel's θi (degrees, at most 4).
        signed: the signed outgoing angles of the model's curves (degrees).
        panels: per angle, a dict: ``model`` ``(len(signed), C)``, ``x`` the data's signed θo (degrees), ``y``
            their values ``(len(x), C)`` (NaN or ≤ 0 not drawn), ``count`` the samples near the plane, ``bands``
            None or percentile -> ``(len(signed), C)`` (2.5, 16, 84, 97.5).
        ylim: the f_r range shown, or None.
        windows: the half-widths of the data's windows, ``(θi, plane)`` in degrees.
    """
    colours = channel_colours(channels)
    fig = new_figure("slices")
    axes = fig.subplots(2, 2).ravel()
    with_bands = False
    for k, ax in enumerate(axes):
        if k >= len(angles):
            ax.set_visible(False)
            continue
        panel = panels[k]
        bands = panel["bands"]
        with_bands = with_bands or bands is not None
        for c, name in enumerate(channels):
            if bands is not None:
                ax.fill_between(signed, bands[2.5][:, c], bands[97.5][:, c], color=colours[c], alpha=0.12, lw=0,
                                label="95 % band" if c == 0 else None)
                ax.fill_between(signed, bands[16][:, c], bands[84][:, c], color=colours[c], alpha=0.25, lw=0,
                                label="68 % band" if c == 0 else None)
            ax.plot(signed, panel["model"][:, c], color=colours[c], lw=1.4, label=f"fit {name}")
            y = panel["y"][:, c]
            ok = np.isfinite(y) & (y > 0)
            ax.plot(panel["x"][ok], y[ok], "o", ms=3.5, mfc="none", color=colours[c], alpha=0.8,
                    label=f"data {name}")
        ax.axvline(angles[k], color="0.5", ls=":", lw=1, label="mirror direction")
        ax.axvline(0.0, color="0.8", lw=0.8)
        ax.set_yscale("log")
        plain_log_labels(ax.yaxis)
        if ylim is not None:
            ax.set_ylim(*ylim)
        ax.set_xlim(-90, 90)
        ax.set_title(f"θi = {angles[k]:.0f}°  ({panel['count']} samples within ±{windows[0]:.0f}° "
                     f"of θi and {windows[1]:.1f}° of the plane)", fontsize=9)
        ax.set_xlabel("signed θo (°): < 0 towards the light, > 0 mirror side")
        ax.set_ylabel("f_r (1/sr)")
        ax.grid(True, which="major", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.suptitle(f"In-plane BRDF slices: data vs fitted {spec}"
                 + (" with posterior 68/95 % bands (shaded; may be thinner than the line)" if with_bands else ""),
                 fontsize=11)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 9), fontsize=8, frameon=False)
    return save(fig, path)


def draw_hemisphere(path, *, spec: str, theta_i: float, grids, names, vmin: float, vmax: float) -> str:
    """The model over the outgoing hemisphere (`brdffit.report.figures.plot_hemisphere`).

    Arguments:
        spec: the fitted model's spec.
        theta_i: the incidence (radians).
        grids: per channel shown, f_r cosθo on the projected disc ``(R, R)``, NaN outside it, at least ``vmin``.
        names: those channels' names.
        vmin, vmax: the log colour scale's range.
    """
    norm = LogNorm(vmin=vmin, vmax=vmax)
    fig = new_figure("hemisphere")
    axes = fig.subplots(1, len(grids), squeeze=False)[0]
    image = None
    t = np.linspace(0, 2 * np.pi, 200)
    for ax, grid, name in zip(axes, grids, names):
        image = ax.imshow(grid, origin="lower", extent=(-1, 1, -1, 1), norm=norm, cmap="inferno")
        for deg in (30, 60):
            ax.plot(np.sin(np.radians(deg)) * np.cos(t), np.sin(np.radians(deg)) * np.sin(t), color="0.6", lw=0.6)
            ax.text(np.sin(np.radians(deg)) * 0.72, np.sin(np.radians(deg)) * 0.72, f"θo={deg}°", color="white",
                    fontsize=7, ha="center", va="center", bbox=dict(fc="0.2", alpha=0.6, lw=0, pad=1))
        ax.plot([-np.sin(theta_i)], [0.0], "c+", ms=10, mew=1.5, label="mirror direction")
        ax.plot([np.sin(theta_i)], [0.0], "wx", ms=7, mew=1.5, label="light (ωi)")
        ax.set_title(f"channel {name}", fontsize=10)
        ax.set_xlabel("sinθo cosφo")
        ax.set_ylabel("sinθo sinφo")
        ax.set_aspect("equal")
        ax.set_facecolor("0.85")
        ax.legend(fontsize=7, loc="lower left", facecolor="0.45", labelcolor="white")
    fig.suptitle(f"Fitted {spec}: f_r cosθo over the outgoing hemisphere, θi = {np.degrees(theta_i):.0f}°, "
                 "φi = 0° (orthographic projection, rim = horizon)", fontsize=11)
    cax = fig.add_axes((0.93, 0.15, 0.015, 0.7))
    fig.colorbar(image, cax=cax, label="f_r cosθo (1/sr), log scale")
    plain_log_labels(cax.yaxis)
    return save(fig, path)


def draw_residuals(path, *, spec: str, channels, edges_h, edges_d, mean, count, bins: int) -> str:
    """The relative residual per (θh, θd) bin (`brdffit.report.figures.plot_residual_map`), one panel per channel
    (at most three), with the arrays of `brdffit.report.figures.residual_map`."""
    shown = list(range(min(mean.shape[0], 3)))
    finite = np.abs(mean[np.isfinite(mean)])
    lim = float(np.percentile(finite, 98)) if finite.size else 1.0
    lim = lim if lim > 0 else 1e-3
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)
    fig = new_figure("residuals")
    axes = fig.subplots(1, len(shown), squeeze=False)[0]
    image = None
    for ax, c in zip(axes, shown):
        image = ax.imshow(np.clip(mean[c], -lim, lim), origin="lower",
                          extent=(edges_h[0], edges_h[-1], edges_d[0], edges_d[-1]), norm=norm, cmap="RdBu_r",
                          aspect="auto")
        ax.set_facecolor("0.8")
        n = count[c].sum()
        rms = float(np.sqrt(np.nanmean(mean[c] ** 2))) if np.isfinite(mean[c]).any() else float("nan")
        ax.set_title(f"channel {channels[c]}: {int(n)} samples, RMS of bin means {rms:.2g}", fontsize=9)
        ax.set_xlabel("θh, half-vector angle (°)")
        ax.set_ylabel("θd, difference angle (°)")
    fig.suptitle(f"Relative residual (model − data)/data of {spec}, mean per {90 / bins:.0f}° bin "
                 "(grey: no data)", fontsize=11)
    cax = fig.add_axes((0.89, 0.15, 0.015, 0.7))
    fig.colorbar(image, cax=cax, label="(model − data) / data")
    return save(fig, path)


def draw_albedo(path, *, spec: str, albedo, names, at_the_view: bool) -> str:
    """The directional albedo curve (`brdffit.report.figures.plot_albedo`): ``albedo`` ``(n, C)`` at n angles from
    0° to 89°, per channel ``names``; ``at_the_view``: the curve is the albedo at each view, against θo."""
    theta = np.linspace(0.0, 89.0, len(albedo))
    colours = channel_colours(names)
    fig = new_figure("albedo")
    ax = fig.subplots()
    for c in range(albedo.shape[1]):
        ax.plot(theta, albedo[:, c], color=colours[c], lw=1.5, label=f"channel {names[c]}")
    ax.axhline(1.0, color="k", ls="--", lw=1, label="energy conservation (a = 1)")
    top = max(1.1, float(np.nanmax(albedo)) * 1.05)
    ax.set_ylim(0.0, top)
    ax.set_xlim(0, 90)
    if at_the_view:
        ax.set_xlabel("θo, viewing angle (°)")
        ax.set_ylabel("albedo at the view a(θo) = ∫ f_r cosθi dωi (1)")
    else:
        ax.set_xlabel("θi, incidence angle (°)")
        ax.set_ylabel("directional albedo a(θi) (1)")
    ax.set_title(f"Directional albedo of the fitted {spec}\nmax {float(np.nanmax(albedo)):.3f}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")
    return save(fig, path)


def draw_spheres(path, *, spec: str, data, fitted, diff, lit, resolution: int) -> str:
    """The sphere previews (`brdffit.report.figures.plot_spheres`): ``data`` and ``fitted`` as displayable images
    (RGB, or grey ``(R, R)``, in [0, 1]), their relative difference ``diff`` and its values on the lit pixels
    ``lit``."""
    fig = new_figure("spheres")
    axes = fig.subplots(1, 3)
    _sphere_panel(axes[0], data, "measurement (k-NN interpolated)")
    _sphere_panel(axes[1], fitted, "fit")
    vmax = float(np.percentile(lit, 99)) if lit.size else 1.0
    image = axes[2].imshow(diff, cmap="magma", vmin=0.0, vmax=max(vmax, 1e-3))
    axes[2].set_title(f"relative difference (median {float(np.median(lit)) if lit.size else 0:.2g})", fontsize=10)
    axes[2].set_xticks([]), axes[2].set_yticks([])
    fig.colorbar(image, ax=axes[2], fraction=0.046, pad=0.04, label="|Y_fit − Y_data| / Y_data")
    fig.suptitle(f"Sphere previews ({resolution}×{resolution} px, key/fill/rim lights, Reinhard tone map): "
                 f"data vs fitted {spec}", fontsize=11)
    return save(fig, path)


def draw_renderer_view(path, *, target: str, images, titles, resolution: int) -> str:
    """The renderer's view (`brdffit.report.figures.plot_renderer_view`): the displayable sphere images of the data,
    the free fit and the target's fit, with their titles."""
    fig = new_figure("renderer")
    for ax, shown, title in zip(fig.subplots(1, 3), images, titles):
        _sphere_panel(ax, shown, title)
    fig.suptitle(f"The renderer's view ({resolution}×{resolution} px, key/fill/rim lights, Reinhard tone map): "
                 f"the data, the best free model and the best model {target} represents", fontsize=11)
    return save(fig, path)


def _sphere_panel(ax, shown, title: str) -> None:
    """A sphere preview in ``ax``: a displayable image (RGB, or grey ``(R, R)``, in [0, 1]), titled, no axes."""
    ax.imshow(shown, cmap="gray" if shown.ndim == 2 else None, vmin=0, vmax=1)
    ax.set_title(title, fontsize=10)
    ax.set_xticks([]), ax.set_yticks([])
