r"""Colour of spectra: CIE 1931 XYZ (2° observer) under illuminant D65, linear sRGB and its display encoding.

The tables (`tables`) are the CIE 1931 2° colour-matching functions x̄, ȳ, z̄ (ISO/CIE 11664-1:2019, CIE 018:2019)
and the relative spectral power S of CIE standard illuminant D65 (ISO/CIE 11664-2, CIE 015:2018 Table 5), at 1 nm
from 360 to 830 nm, stored in ``brdffit/data/cie_1931_2deg_d65.csv`` (written and checked against colour-science by
``scripts/cie_tables.py``; the file's opening lines name the sources).

**Spectrum -> XYZ.** A reflectance (or BRDF, or radiance factor) ρ known at bands λ_1 < ... < λ_B is read as the
piecewise-linear function through the band values, held at the first and last band's value outside [λ_1, λ_B]
(the nearest measured value, which CIE 015 and ASTM E308 recommend for data that stop short of the range), and
summed with the 1 nm tables (CIE 015:2018 §7, the tristimulus values of an object colour at Δλ = 1 nm):

.. math::  X = k \sum_\lambda S(\lambda) \bar x(\lambda) \rho(\lambda) \Delta\lambda, \quad
           k = 1 / \sum_\lambda S(\lambda) \bar y(\lambda) \Delta\lambda,

likewise Y with ȳ and Z with z̄: the perfect white reflector (ρ = 1) has Y = 1. Linear interpolation never
overshoots (the value between two bands lies between theirs, so a reflectance stays within [0, 1] at a sharp
absorption edge, where Sprague's or Lagrange's polynomials ring), takes bands at any spacing and start (ASTM E308
tabulates weights for 10 and 20 nm from fixed starts) and is how the standard's own 1 nm D65 table is made from its
5 nm one. Its cost: on smooth spectra sampled every 10 nm it differs from the weights of ASTM E308 (colour-science's
default method, which interpolates by Lagrange polynomials) by up to 1.4e-3 in X, Y or Z (tests/test_colour.py);
with the spectrum linearly interpolated to 1 nm, colour-science's plain integration agrees to rounding.
So XYZ = W ρ with a 3 × B matrix W (`SpectralColour.xyz_weights`).

**XYZ -> linear sRGB.** sRGB's primaries are those of IEC 61966-2-1:1999 (ITU-R BT.709): R (0.64, 0.33),
G (0.30, 0.60), B (0.15, 0.06). The RGB -> XYZ matrix is the normalised primary matrix of these primaries for the
white point (SMPTE RP 177-1993; the construction by which IEC 61966-2-1 derives its 4-digit matrices), with the
white taken as the XYZ of the perfect reflector under the tabulated D65, (x, y) = (0.312727, 0.329023), instead of
the rounded (0.3127, 0.3290): a flat spectrum of 1 then maps to linear sRGB (1, 1, 1) to rounding. With the
standard's rounded matrix it maps to (1.00001, 1.00008, 0.99983) and with the rounded white to (1.00016, 0.99998,
0.99976); the entries of `XYZ_TO_LINEAR_SRGB` differ from the standard's 4-digit ones by at most 3.7e-4.

**Models.** Where a spectral model is linear in every per-band parameter (the amplitudes: ρd, ks, a base colour)
and its other parameters are shared, the BRDF in band j is f_j = o + Σ_p a_{p,j} B_p (o and B_p independent of the
band), and the linear sRGB of the model is exactly the same model with each amplitude's spectrum converted:
M W f = o M W 1 + Σ_p (M W a_p) B_p, where M W 1 = (1, 1, 1) by the white point above (`rgb_model`). A per-band
parameter that is not an amplitude (a conductor's η and k, glTF's specular colour when freed) gives no such model;
`rgb_model` refuses it unless its value is the same in every band.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

__all__ = ["ColourError", "TABLE_FILE", "tables", "white_xyz", "SRGB_PRIMARIES", "SRGB_WHITE_XY",
           "normalised_primary_matrix", "LINEAR_SRGB_TO_XYZ", "XYZ_TO_LINEAR_SRGB", "xyz_to_xy",
           "xyz_to_linear_srgb", "linear_srgb_to_xyz", "srgb_encode", "SpectralColour", "spectral_colour",
           "wavelengths_of", "rgb_model", "measurements_to_rgb"]

TABLE_FILE = "data/cie_1931_2deg_d65.csv"  # inside the package (package data)
# IEC 61966-2-1:1999 §5.1 (= ITU-R BT.709-6 item 1.3/1.4): chromaticities of the sRGB primaries and of its white.
SRGB_PRIMARIES = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
SRGB_WHITE_XY = (0.3127, 0.3290)


class ColourError(ValueError):
    """Wavelengths that cannot be converted, or a model that has no exact RGB equivalent (the message says why)."""


@functools.lru_cache(maxsize=1)
def tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The colour tables of the package, 360-830 nm at 1 nm.

    Returns:
        ``(wavelengths (471,) nm, cmfs (471, 3) x̄ ȳ z̄, d65 (471,))``.
    """
    from importlib import resources

    with resources.files("brdffit").joinpath(TABLE_FILE).open("r", encoding="utf-8") as handle:
        table = np.loadtxt(handle, delimiter=",", comments="#")
    columns = table[:, 0].copy(), table[:, 1:4].copy(), table[:, 4].copy()
    for column in columns:  # cached and shared by every conversion: read-only
        column.flags.writeable = False
    return columns


@functools.lru_cache(maxsize=1)
def _object_weights() -> np.ndarray:
    """k S(λ) x̄(λ) Δλ, ... at the table's 1 nm grid, ``(471, 3)``, with k making Σ of the ȳ column 1."""
    _, cmfs, d65 = tables()
    weights = d65[:, None] * cmfs  # Δλ = 1 nm cancels in k
    weights /= weights[:, 1].sum()
    weights.flags.writeable = False  # cached and shared by every conversion
    return weights


def white_xyz() -> np.ndarray:
    """XYZ of the perfect white reflector under the tabulated D65 (Y = 1): (0.95047, 1, 1.08883)."""
    return _object_weights().sum(axis=0)


def normalised_primary_matrix(primaries, white) -> np.ndarray:
    """The RGB -> XYZ matrix of three primaries and a white (SMPTE RP 177-1993 §3.3): the columns are the primaries'
    XYZ (x/y, 1, (1 − x − y)/y), each scaled so that RGB (1, 1, 1) gives ``white``.

    Arguments:
        primaries: ((x_R, y_R), (x_G, y_G), (x_B, y_B)).
        white: the white's XYZ.

    Returns:
        ``(3, 3)``.
    """
    columns = np.array([[x / y, 1.0, (1.0 - x - y) / y] for x, y in primaries]).T
    return columns * np.linalg.solve(columns, np.asarray(white, dtype=float))


LINEAR_SRGB_TO_XYZ = normalised_primary_matrix(SRGB_PRIMARIES, white_xyz())
XYZ_TO_LINEAR_SRGB = np.linalg.inv(LINEAR_SRGB_TO_XYZ)
LINEAR_SRGB_TO_XYZ.flags.writeable = XYZ_TO_LINEAR_SRGB.flags.writeable = False


def xyz_to_xy(xyz) -> np.ndarray:
    """Chromaticity x = X/(X + Y + Z), y = Y/(X + Y + Z) (CIE 015:2018 §7.3); ``(..., 3)`` -> ``(..., 2)``."""
    xyz = np.asarray(xyz, dtype=float)
    return xyz[..., :2] / xyz.sum(axis=-1, keepdims=True)


def xyz_to_linear_srgb(xyz) -> np.ndarray:
    """Linear sRGB of XYZ (`XYZ_TO_LINEAR_SRGB`); ``(..., 3)`` -> ``(..., 3)``, not clipped (out of gamut is < 0)."""
    return np.asarray(xyz, dtype=float) @ XYZ_TO_LINEAR_SRGB.T


def linear_srgb_to_xyz(rgb) -> np.ndarray:
    """XYZ of linear sRGB (`LINEAR_SRGB_TO_XYZ`); ``(..., 3)`` -> ``(..., 3)``."""
    return np.asarray(rgb, dtype=float) @ LINEAR_SRGB_TO_XYZ.T


def srgb_encode(linear) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1:1999, Eq. 5): linear [0, 1] -> display values [0, 1],
    V = 12.92 L for L <= 0.0031308, else 1.055 L^(1/2.4) − 0.055; inputs are clipped to [0, 1] first.

    Arguments:
        linear: linear values, any shape.

    Returns:
        Encoded values in [0, 1], same shape.
    """
    x = np.clip(np.asarray(linear, dtype=float), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


@dataclasses.dataclass(frozen=True)
class SpectralColour:
    """The linear map from values at a set of bands to XYZ and linear sRGB (the module doc's method).

    Attributes:
        wavelengths: the bands, nm, in the order of the channels.
        xyz_weights: ``(3, B)``: XYZ = xyz_weights @ values.
        rgb_weights: ``(3, B)``: linear sRGB = rgb_weights @ values; each row sums to 1 (to rounding).
        outside: the share of Σ S ȳ (the luminance of a flat spectrum) at wavelengths outside the bands' range,
            where the spectrum is held at the nearest band's value.
    """

    wavelengths: tuple
    xyz_weights: np.ndarray = dataclasses.field(repr=False)
    rgb_weights: np.ndarray = dataclasses.field(repr=False)
    outside: float

    @property
    def bands(self) -> int:
        return len(self.wavelengths)

    def xyz(self, values) -> np.ndarray:
        """XYZ of values at the bands: ``(..., B)`` -> ``(..., 3)``."""
        return self._apply(values, self.xyz_weights)

    def linear_srgb(self, values) -> np.ndarray:
        """Linear sRGB of values at the bands: ``(..., B)`` -> ``(..., 3)`` (not clipped)."""
        return self._apply(values, self.rgb_weights)

    def _apply(self, values, weights) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        if values.shape[-1:] != (self.bands,):
            raise ColourError(f"values of shape {values.shape} do not end in the {self.bands} bands "
                              f"({self.wavelengths[0]:g}-{self.wavelengths[-1]:g} nm) of this conversion")
        return values @ weights.T

    def describe(self) -> str:
        """One line (ASCII) naming the method, for the comments of a converted export and for the docs."""
        low, high = min(self.wavelengths), max(self.wavelengths)
        held = ("" if self.outside == 0.0 else
                f" and held at the nearest band's value outside {low:g}-{high:g} nm ({100.0 * self.outside:.2g}% "
                "of the luminance of a flat spectrum lies there)")
        return (f"{self.bands} spectral bands ({low:g}-{high:g} nm) converted to linear sRGB (IEC 61966-2-1 "
                "primaries, white balanced to D65): CIE 1931 XYZ (2-degree observer) under CIE D65 with a perfect "
                "white reflector at Y = 1, the spectrum interpolated linearly between the bands" + held
                + ", summed with the CIE 1 nm tables (CIE 015:2018)")


def spectral_colour(wavelengths, where: str = "wavelengths") -> SpectralColour:
    """The conversion of values at these bands to XYZ and linear sRGB.

    Arguments:
        wavelengths: one wavelength per channel, nm (any order; no two equal).
        where: what the wavelengths are, for messages (a file and field, e.g. ``"scan.astm: meta wavelengths_nm"``).

    Returns:
        The `SpectralColour`.

    Raises:
        ColourError: no wavelength, one that is not a finite positive number, two equal, or none inside the
            tables' 360-830 nm.
    """
    values = _checked(wavelengths, where)
    grid, _, _ = tables()
    if values.max() < grid[0] or values.min() > grid[-1]:
        raise ColourError(f"{where}: every band ({values.min():g}-{values.max():g} nm) lies outside the CIE tables' "
                          f"{grid[0]:g}-{grid[-1]:g} nm, where the eye sees nothing; no colour can be computed")
    return _spectral_colour(tuple(float(v) for v in values))


def _checked(wavelengths, where: str) -> np.ndarray:
    """The wavelengths as a float vector, or a ColourError naming ``where`` and what was expected."""
    try:
        values = np.asarray(wavelengths, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ColourError(f"{where}: expected a list of wavelengths in nm, got {wavelengths!r}") from None
    if values.size == 0:
        raise ColourError(f"{where}: no wavelength given; a spectrum needs one wavelength (nm) per channel")
    bad = ~np.isfinite(values) | (values <= 0.0)
    if bad.any():
        raise ColourError(f"{where}: wavelength {int(np.argmax(bad))} is {float(values[bad][0])!r}; expected a "
                          "positive number of nm")
    if len(np.unique(values)) != values.size:
        twice = sorted({float(v) for v in values if np.sum(values == v) > 1})
        raise ColourError(f"{where}: the wavelength {twice[0]:g} nm is given twice; each band needs its own")
    return values


@functools.lru_cache(maxsize=64)
def _spectral_colour(wavelengths: tuple) -> SpectralColour:
    grid, _, _ = tables()
    weights = _object_weights()
    bands = np.asarray(wavelengths)
    order = np.argsort(bands)
    # Hat functions: the linear interpolation of the unit vector e_j at the 1 nm grid (np.interp holds the end
    # values outside the range), so ρ(λ) = Σ_j ρ_j h_j(λ) and XYZ = Σ_j ρ_j Σ_λ w(λ) h_j(λ).
    hats = np.empty((len(grid), len(bands)))
    for j, column in enumerate(np.eye(len(bands))[order].T):
        hats[:, j] = np.interp(grid, bands[order], column)
    xyz_weights = weights.T @ hats
    rgb_weights = XYZ_TO_LINEAR_SRGB @ xyz_weights
    inside = (grid >= bands.min()) & (grid <= bands.max())
    outside = float(weights[~inside, 1].sum())
    for array in (xyz_weights, rgb_weights):
        array.flags.writeable = False
    return SpectralColour(wavelengths, xyz_weights, rgb_weights, 0.0 if outside < 1e-12 else outside)


def wavelengths_of(meta, channels: int, where: str = "measurements") -> list | None:
    """The wavelengths of spectral channels kept in measurements' metadata (``meta["wavelengths_nm"]``, which the
    ASTM E1392 reader sets), or None where there are none.

    Arguments:
        meta: the `Measurements.meta` dict (or None).
        channels: the number of channels they must name.
        where: what ``meta`` belongs to, for messages.

    Returns:
        A list of ``channels`` floats (nm), or None.

    Raises:
        ColourError: ``wavelengths_nm`` present but not one positive wavelength per channel, each once (bands
            outside the visible range are left to `spectral_colour` to refuse).
    """
    found = (meta or {}).get("wavelengths_nm")
    if found is None:
        return None
    field = f"{where}: meta wavelengths_nm"
    if not isinstance(found, (list, tuple)) or len(found) != channels:
        raise ColourError(f"{field} must list one wavelength (nm) per channel ({channels}), got {found!r}")
    return [float(v) for v in _checked(found, field)]


def rgb_model(model, wavelengths):
    """A spectral model as the linear sRGB model of the same family (the module doc's **Models**).

    Every parameter shared by the bands is kept; every amplitude (a colour parameter declared linear) becomes the
    linear sRGB of its spectrum, an exact map since the BRDF is affine in the amplitudes with a white offset. A
    negative result (a colour outside the sRGB gamut) is set to 0 and said in the returned line.

    Arguments:
        model: a `brdffit.Model` with one channel per wavelength.
        wavelengths: the bands, nm.

    Returns:
        ``(rgb, line)``: the 3-channel `brdffit.Model` and one line (ASCII) stating the conversion (`SpectralColour.
        describe`) and whether it is exact.

    Raises:
        ColourError: a channel count other than the number of wavelengths, or a per-band parameter that is not an
            amplitude and differs between bands (no RGB model of that family equals the spectral one in sRGB).
    """
    from .models import Model
    from .models.layout import layout

    conversion = spectral_colour(wavelengths, "the wavelengths given")
    if model.channels != conversion.bands:
        raise ColourError(f"model {model.spec!r} has {model.channels} channels but {conversion.bands} wavelengths "
                          "were given; a spectral model needs one wavelength per channel")
    params, clipped = {}, []
    for slot in model.layout.slots:
        value = np.asarray(model.params[slot.name], dtype=float)
        if not slot.spec.colour:
            params[slot.name] = value
        elif slot.spec.linear:
            rgb = conversion.linear_srgb(value)
            if np.any(rgb < 0.0):
                clipped.append(f"{slot.name} {', '.join(format(v, '.3g') for v in rgb)}")
            params[slot.name] = np.maximum(rgb, 0.0)
        elif np.all(value == value[0]):
            params[slot.name] = np.full(3, value[0])
        else:
            raise ColourError(
                f"model {model.spec!r}: its per-band parameter {slot.name!r} ({slot.spec.doc}) is not an amplitude "
                f"and varies between the {conversion.bands} bands ({value.min():.4g} to {value.max():.4g}), so no "
                "RGB model of this family equals the spectral model in sRGB. Fit the RGB data instead "
                "(brdffit.colour.measurements_to_rgb converts spectral measurements), or fit a model whose per-band "
                "parameters are amplitudes (lambert, ggx or cook-torrance with Schlick or dielectric Fresnel, gltf)")
    table = layout(model.lobes, 3)
    rgb = Model(params={spec.name: spec.initial(3) for spec in table.specs}, lobes=model.lobes, channels=3)
    rgb = rgb.replace(**params)
    verdict = ("exact: the shape parameters kept, each amplitude's spectrum mapped by the same linear map (the "
               "BRDF is linear in the amplitudes)")
    if clipped:
        verdict = ("approximate: outside the sRGB gamut, negative linear sRGB set to 0 (" + "; ".join(clipped)
                   + "); otherwise the shape parameters kept and each amplitude's spectrum mapped linearly")
    return rgb, f"colour: {conversion.describe()}; {verdict}"


def measurements_to_rgb(measurements, wavelengths=None):
    """Spectral measurements as linear sRGB measurements (channels R, G, B), to fit an RGB model to.

    A sample with a band missing (NaN) has no colour: its R, G and B are missing. A negative value (a colour
    outside the sRGB gamut; measurements are never negative) is set to 0, and ``meta["colour"]`` counts them. σ is
    propagated for independent bands, σ_c = (Σ_j W_cj² σ_j²)^½ with W the `SpectralColour.rgb_weights`.

    Arguments:
        measurements: `brdffit.Measurements` with one channel per band.
        wavelengths: the bands, nm; default ``measurements.meta["wavelengths_nm"]``.

    Returns:
        New `Measurements`: the same directions and weights, the colour conversion recorded in
        ``meta["colour"]`` and the wavelengths removed.

    Raises:
        ColourError: no wavelengths, or not one per channel.
    """
    source = (measurements.meta or {}).get("source", "measurements")
    if wavelengths is None:
        wavelengths = wavelengths_of(measurements.meta, len(measurements.channels), str(source))
        if wavelengths is None:
            raise ColourError(f"{source}: no meta wavelengths_nm; give the wavelengths of the channels (nm)")
    conversion = spectral_colour(wavelengths, f"{source}: wavelengths")
    if len(measurements.channels) != conversion.bands:
        raise ColourError(f"{source}: {len(measurements.channels)} channels but {conversion.bands} wavelengths")
    values = conversion.linear_srgb(measurements.values)  # NaN in any band gives NaN in all three
    negative = int(np.sum(values < 0.0))
    sigma = None
    if measurements.sigma is not None:
        sigma = np.sqrt(np.asarray(measurements.sigma, dtype=float) ** 2 @ (conversion.rgb_weights ** 2).T)
    meta = {k: v for k, v in (measurements.meta or {}).items() if k != "wavelengths_nm"}
    meta["colour"] = conversion.describe() + (f"; {negative} values outside the sRGB gamut (negative) set to 0"
                                              if negative else "")
    return measurements.replace(values=np.maximum(values, 0.0, where=~np.isnan(values), out=values.copy()),
                                sigma=sigma, channels=["R", "G", "B"], meta=meta)
