"""Interpolation of measured data: a measured BRDF estimated at new direction pairs by its k nearest samples.

To see a measurement in a scene, its BRDF is needed at the scene's rows (`brdffit.scene.Scene.radiance_interpolated`,
`brdffit.render`, `brdffit.select` with a scene). `interpolate` weights the k nearest measured samples by inverse
distance (Shepard 1968), w = 1 / d^power, in coordinates that respect the symmetries of a BRDF (`_features`). With
h = normalise(ωi + ωo) and δ = (ωi − ωo)/2 (|δ| = sinθd, δ ⊥ h), the Rusinkiewicz angles give
cosθi − cosθo = 2 δz = −2 sinθh sinθd cosφd. Swapping ωi and ωo keeps h and flips δ, so features built from h,
|δ| and even products of δ make reciprocity exact (bit for bit):

- ``isotropic=True``: (3 θh, θd, |cosθi − cosθo|/2) = (3 θh, θd, sinθh sinθd |cosφd|), invariant under rotation
  about the normal and under mirroring in a plane through it. The factor 3 on θh (`THETA_H_WEIGHT`) makes
  distances along θh, where a specular lobe changes fastest, count more.
- ``isotropic=False``: (3 θh cosφh, 3 θh sinφh, θd, sinθh sinθd cos2φd, sinθh sinθd sin2φd): the half vector's
  azimuth is kept (polar embedding, continuous at the normal) and φd enters modulo π as a doubled angle.

Missing (NaN) values are left out channel by channel (one k-d tree per pattern of missing values); a query with
a direction at or below the horizon gives 0; a query outside the measured range gets the value of the nearest
samples, without extrapolation. docs/scenes.md has the measured accuracy.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .measurements import Measurements

__all__ = [
    "interpolate",
    "THETA_H_WEIGHT",
]

# Weight of θh (radians) against θd and |cosθi − cosθo|/2 in the interpolation features. A specular lobe varies
# fastest with θh, so distances along θh count more; 3 gave the smallest error on lambert+ward data with α from
# 0.1 to 0.3 among 1, 1.5, 2, 3, 4, 5 (docs/scenes.md).
THETA_H_WEIGHT = 3.0

# Distances below this are treated as an exact hit by the inverse-distance weights.
_MIN_DISTANCE = 1e-12


def _normalise_rows(name: str, w) -> np.ndarray:
    # Directions as rows (M, 3), checked and normalised (`Scene.from_directions` uses it too).
    w = np.array(w, dtype=float)
    if w.ndim == 1 and w.shape == (3,):
        w = w[None, :]
    if w.ndim != 2 or w.shape[1] != 3:
        raise ValueError(f"{name} must have shape (M, 3), got {w.shape}")
    norm = np.linalg.norm(w, axis=1, keepdims=True)
    if not np.all(np.isfinite(w)) or np.any(norm == 0.0):
        row = int(np.flatnonzero(~np.all(np.isfinite(w), axis=1) | (norm[:, 0] == 0.0))[0])
        raise ValueError(f"{name}: row {row} is not a finite non-zero direction: {w[row].tolist()}")
    return w / norm


def _features(wi: np.ndarray, wo: np.ndarray, isotropic: bool) -> np.ndarray:
    r"""Coordinates of direction pairs in which nearby points have similar BRDF values.

    With h = (ωi + ωo)/|ωi + ωo| and δ = (ωi − ωo)/2 (so |δ| = sinθd and δ ⊥ h), the Rusinkiewicz (1998) angles
    satisfy cosθi − cosθo = 2 δz = −2 sinθh sinθd cosφd. Swapping ωi and ωo (reciprocity) keeps h and flips δ,
    so every feature below is built from h, |δ| and products with an even number of δ factors: reciprocity holds
    exactly, in floating point too.

    Isotropic: (w θh, θd, |cosθi − cosθo|/2) = (w θh, θd, sinθh sinθd |cosφd|), invariant under rotation about
    the normal and under mirroring in a plane through it (the usual assumption behind "f depends on θi, θo and
    |φo − φi|"). The third coordinate carries the φd dependence with its natural weight sinθh: at θh = 0 every φd is
    the same configuration up to a rotation, so there it vanishes. w = `THETA_H_WEIGHT`.

    Anisotropic: (w θh cosφh, w θh sinφh, θd, sinθh sinθd cos2φd, sinθh sinθd sin2φd): h as a polar embedding
    (continuous at the normal) and φd modulo π (reciprocity) as a doubled angle. With P = sinθh sinθd cosφd = −δz
    and Q = sinθh sinθd sinφd = (h × δ)z, the last two are (P² − Q², 2PQ)/(sinθh sinθd).
    """
    s = wi + wo
    h = s / np.maximum(np.linalg.norm(s, axis=1, keepdims=True), 1e-300)
    delta = 0.5 * (wi - wo)
    theta_h = np.arccos(np.clip(h[:, 2], -1.0, 1.0))
    theta_d = np.arcsin(np.clip(np.linalg.norm(delta, axis=1), 0.0, 1.0))
    p = -delta[:, 2]
    if isotropic:
        return np.stack([THETA_H_WEIGHT * theta_h, theta_d, np.abs(p)], axis=1)
    q = h[:, 0] * delta[:, 1] - h[:, 1] * delta[:, 0]
    radius = np.hypot(p, q)
    safe = np.where(radius > 0.0, radius, 1.0)
    sin_h = np.hypot(h[:, 0], h[:, 1])
    safe_h = np.where(sin_h > 0.0, sin_h, 1.0)
    hx = np.where(sin_h > 0.0, h[:, 0] / safe_h, 0.0)
    hy = np.where(sin_h > 0.0, h[:, 1] / safe_h, 0.0)
    return np.stack([THETA_H_WEIGHT * theta_h * hx, THETA_H_WEIGHT * theta_h * hy, theta_d,
                     (p * p - q * q) / safe, 2.0 * p * q / safe], axis=1)


def interpolate(measurements: Measurements, wi, wo, k: int = 8, isotropic: bool = True,
                power: float = 2.0) -> np.ndarray:
    r"""Estimate a measured BRDF at new direction pairs (scattered-data interpolation).

    Inverse-distance weighting (Shepard 1968) of the k nearest measured samples, found with
    `scipy.spatial.cKDTree` in coordinates that respect the symmetries of a BRDF (`_features`): reciprocity
    always, and with ``isotropic`` rotation about the normal (and mirror symmetry). The coordinates are
    half/difference angles, (3 θh, θd, |cosθi − cosθo|/2) for isotropic data, which resolve the specular peak
    better than (θi, θo, |φo − φi|) (docs/scenes.md has the measured accuracy):

        f(q) = Σ_j w_j f_j / Σ_j w_j,   w_j = 1 / max(d_j, 1e-12)^power.

    Missing (NaN) values are ignored channel by channel. A query with either direction at or below the horizon
    gives 0. Outside the measured range (e.g. beyond the largest measured θ) the estimate is that of the nearest
    samples: no extrapolation.

    Arguments:
        measurements: the measured BRDF.
        wi: ``(M, 3)`` directions to the light, local frame (normalised here).
        wo: ``(M, 3)`` directions to the detector.
        k: number of neighbours (fewer if fewer samples are valid).
        isotropic: use the isotropic coordinates; False keeps the azimuth of the half vector (anisotropic data).
        power: exponent of the inverse-distance weights.

    Returns:
        ``(M, C)`` NumPy array of f_r estimates in 1/sr.

    Raises:
        ValueError: bad shapes, k < 1, or a channel with no measured value at all.
    """
    wi, wo = _normalise_rows("wi", wi), _normalise_rows("wo", wo)
    if wi.shape != wo.shape:
        raise ValueError(f"wi and wo must have the same shape, got {wi.shape} and {wo.shape}")
    k = int(k)
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    values = np.asarray(measurements.values, dtype=float)
    out = np.zeros((wi.shape[0], values.shape[1]))
    above = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
    if not above.any():
        return out
    sample_features = _features(measurements.wi(), measurements.wo(), isotropic)
    query = _features(wi[above], wo[above], isotropic)
    valid = np.isfinite(values)
    # One tree per distinct pattern of missing values (usually one for all channels).
    groups: dict[bytes, list[int]] = {}
    for c in range(values.shape[1]):
        groups.setdefault(np.packbits(valid[:, c]).tobytes(), []).append(c)
    for channels in groups.values():
        rows = np.flatnonzero(valid[:, channels[0]])
        if rows.size == 0:
            names = ", ".join(measurements.channels[c] for c in channels)
            raise ValueError(f"channel(s) {names} have no measured value to interpolate")
        kk = min(k, rows.size)
        dist, idx = cKDTree(sample_features[rows]).query(query, k=kk)
        dist, idx = dist.reshape(len(query), kk), idx.reshape(len(query), kk)
        weight = 1.0 / np.maximum(dist, _MIN_DISTANCE) ** power
        weight /= weight.sum(axis=1, keepdims=True)
        neighbours = values[rows][:, channels][idx]  # (Q, k, len(channels))
        out[np.ix_(np.flatnonzero(above), channels)] = np.einsum("qk,qkc->qc", weight, neighbours)
    return out
