r"""MERL binary BRDF tables (Matusik, Pfister, Brand & McMillan, "A data-driven reflectance model", SIGGRAPH 2003).

File layout (little endian): three int32 dimensions ``90, 90, 180``, then three tables of 90·90·180 = 1,458,000
float64 each, in R, G, B order. A stored number times the channel scale (1/1500, 1.15/1500, 1.66/1500) is f_r in
1/sr; a negative stored number marks a cell that was not measured and is read as missing (NaN), never clamped.

The cells are indexed by Rusinkiewicz (1998) half/difference angles of an isotropic BRDF (`brdffit.geometry`,
`to_half_diff`), with φh ignored:

- θh (polar angle of the half vector) by the square-root rule: index ⌊√(θh / (π/2)) · 90⌋, so cell i covers
  θh ∈ [(i/90)², ((i+1)/90)²] · π/2 and its centre (the midpoint in the square-root scale) is
  ((i + ½)/90)² · π/2 — fine cells near the specular peak;
- θd by ⌊θd / (π/2) · 90⌋, cell j covering [j, j+1] · π/180, centre (j + ½) · π/180;
- φd folded into [0, π) by reciprocity (φd >= π -> φd − π), index ⌊φd / π · 180⌋, centre (k + ½) · π/180.

Every index is clamped to its range, as in MERL's reference code (``BRDFRead.cpp``).

**Cell measure.** For a fixed ωi the map h -> ωo has dωo = 4 (ωo·h) dωh = 4 cosθd dωh, and for a fixed h the map
ωd -> ωi is a rotation, so dωi dωo = 4 cosθd dωh dωd = 4 cosθd sinθh sinθd dθh dφh dθd dφd. A cell stands for
all φh (factor 2π, isotropy) and for φd and φd + π (factor 2, reciprocity), so its measure is

.. math::
    w_{ijk} = 2 \cdot 2\pi \cdot [\cos\theta_h]^{a_i}_{b_i} \cdot [\cos 2\theta_d]^{c_j}_{d_j} \cdot \pi/180

(``[g]^a_b = g(a) − g(b)``, ``a, b`` and ``c, d`` the cell's θh and θd edges). The measures of all cells add up to
8π², the measure of all pairs (ωi, ωo) whose half vector lies above the surface; the cells with both directions
above the horizon add up to about 4π² = (2π)², the measure of the two hemispheres.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np

from ..arrays import jitted
from ..measurements import MeasurementError, Measurements
from ._common import FormatError, atomic_path, read_file_bytes
from .tabulated import DEFAULT_MAX_THETA, DEFAULT_PAIRS, DEFAULT_SAMPLING, check_sampling, grid_patch, over_directions

__all__ = ["MerlTable", "read_merl", "write_merl", "looks_like_merl", "DIMS", "SCALES", "theta_h_index",
           "theta_d_index", "phi_d_index", "theta_h_centre", "theta_d_centre", "phi_d_centre", "cell_weights",
           "cell_angles"]

DIMS = (90, 90, 180)  # θh, θd, φd
N_CELLS = DIMS[0] * DIMS[1] * DIMS[2]  # 1,458,000
SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)  # R, G, B
HEADER_BYTES = 12
FILE_BYTES = HEADER_BYTES + 3 * N_CELLS * 8  # 34,992,012
MISSING_RAW = -1.0  # what `write_merl` stores in a cell it has no value for (the MERL distribution uses negatives)
CHANNELS = ("R", "G", "B")

_HALF_PI = math.pi / 2


# -------------------------------------------------------------------------------------------- index <-> angle
def theta_h_index(theta_h) -> np.ndarray:
    """Cell index of θh (radians) by the square-root rule, clamped to [0, 89]."""
    t = np.clip(np.asarray(theta_h, dtype=float), 0.0, _HALF_PI)
    return np.clip(np.floor(np.sqrt(t / _HALF_PI) * DIMS[0]), 0, DIMS[0] - 1).astype(np.intp)


def theta_d_index(theta_d) -> np.ndarray:
    """Cell index of θd (radians), clamped to [0, 89]."""
    t = np.asarray(theta_d, dtype=float)
    return np.clip(np.floor(t / _HALF_PI * DIMS[1]), 0, DIMS[1] - 1).astype(np.intp)


def phi_d_index(phi_d) -> np.ndarray:
    """Cell index of φd (radians) after folding it into [0, π) by reciprocity, clamped to [0, 179]."""
    p = np.mod(np.asarray(phi_d, dtype=float), 2 * math.pi)
    p = np.where(p >= math.pi, p - math.pi, p)
    return np.clip(np.floor(p / math.pi * DIMS[2]), 0, DIMS[2] - 1).astype(np.intp)


def theta_h_centre(i) -> np.ndarray:
    """θh at the centre of cell ``i``: ((i + ½)/90)² · π/2 (the midpoint in the square-root scale)."""
    return ((np.asarray(i, dtype=float) + 0.5) / DIMS[0]) ** 2 * _HALF_PI


def theta_d_centre(j) -> np.ndarray:
    """θd at the centre of cell ``j``: (j + ½) · π/180."""
    return (np.asarray(j, dtype=float) + 0.5) / DIMS[1] * _HALF_PI


def phi_d_centre(k) -> np.ndarray:
    """φd at the centre of cell ``k``: (k + ½) · π/180."""
    return (np.asarray(k, dtype=float) + 0.5) / DIMS[2] * math.pi


@functools.lru_cache(maxsize=1)
def cell_weights() -> np.ndarray:
    """The measure of every cell in (ωi, ωo) space (module docstring), shape (90, 90, 180); read-only."""
    edges_h = (np.arange(DIMS[0] + 1) / DIMS[0]) ** 2 * _HALF_PI
    edges_d = np.arange(DIMS[1] + 1) / DIMS[1] * _HALF_PI
    w_h = np.cos(edges_h[:-1]) - np.cos(edges_h[1:])
    w_d = np.cos(2 * edges_d[:-1]) - np.cos(2 * edges_d[1:])
    w_p = math.pi / DIMS[2]
    w = 2.0 * 2.0 * math.pi * w_h[:, None, None] * w_d[None, :, None] * np.full(DIMS[2], w_p)[None, None, :]
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=1)
def cell_angles(phi_h: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(θi, φi, θo, φo) of every cell centre at azimuth φh of the half vector, each shape (90, 90, 180), read-only.

    A direction below the horizon has θ > π/2 (such cells hold no measurement of a real surface).
    """
    from ..geometry import from_half_diff

    th, td, pd = np.meshgrid(theta_h_centre(np.arange(DIMS[0])), theta_d_centre(np.arange(DIMS[1])),
                             phi_d_centre(np.arange(DIMS[2])), indexing="ij")
    out = tuple(np.asarray(a, dtype=np.float64) for a in jitted(from_half_diff)(th, np.full_like(th, phi_h), td, pd))
    for a in out:
        a.flags.writeable = False
    return out


def _above_horizon(theta_i, theta_o) -> np.ndarray:
    return (theta_i < _HALF_PI) & (theta_o < _HALF_PI)


# --------------------------------------------------------------------------------------------------- the table
@dataclasses.dataclass(frozen=True, eq=False)
class MerlTable:
    """A whole MERL table: f_r in 1/sr at every cell, NaN where the cell holds no value.

    Fields:
        data: float64, shape (3, 90, 90, 180) (channel R, G, B; θh, θd, φd indices); read-only.
        source: the file it was read from, if any.
    """

    data: np.ndarray
    source: str | None = None

    def __post_init__(self):
        data = np.array(self.data, dtype=np.float64)
        if data.shape != (3, *DIMS):
            raise ValueError(f"a MERL table has shape (3, 90, 90, 180), got {data.shape}")
        data.flags.writeable = False
        object.__setattr__(self, "data", data)

    def __repr__(self) -> str:
        missing = np.isnan(self.data).any(axis=0).mean()
        return f"MerlTable(source={self.source!r}, missing cells={missing:.1%})"

    @property
    def valid(self) -> np.ndarray:
        """(90, 90, 180) bool: True where every channel has a value."""
        return np.isfinite(self.data).all(axis=0)

    @classmethod
    def from_model(cls, model, chunk: int = 1 << 18) -> "MerlTable":
        """Tabulate a brdffit model at the cell centres (φh = 0).

        Arguments:
            model: a `brdffit.Model` with 3 channels (R, G, B) or 1 channel (copied to all three). MERL tables are
                isotropic: an anisotropic model is tabulated along φh = 0 only.
            chunk: cells evaluated per call (bounds the memory used).

        Returns:
            The table; cells whose centre has ωi or ωo below the horizon are missing (NaN), as in the MERL
            database, which holds no value there.
        """
        from ..models import evaluate

        channels = int(getattr(model, "channels", 0))
        if channels not in (1, 3):
            raise ValueError(f"a MERL table has 3 channels (R, G, B); the model has {channels} (use 3, or 1 for "
                             "grey)")
        theta_i, phi_i, theta_o, phi_o = (a.reshape(-1) for a in cell_angles(0.0))
        above = np.flatnonzero(_above_horizon(theta_i, theta_o))
        out = np.full((N_CELLS, 3), np.nan)
        chunk = min(int(chunk), len(above))
        for start in range(0, len(above), chunk):
            rows = above[start:start + chunk]
            padded = np.pad(rows, (0, chunk - len(rows)), mode="edge")  # one compiled shape for every chunk
            f = np.asarray(evaluate(model, theta_i[padded], phi_i[padded], theta_o[padded], phi_o[padded]),
                           dtype=np.float64)[:len(rows)]
            out[rows] = f if channels == 3 else np.repeat(f, 3, axis=1)
        return cls(out.T.reshape(3, *DIMS))

    def lookup(self, theta_i, phi_i, theta_o, phi_o, *, interpolation: str = "nearest") -> np.ndarray:
        """The tabulated f_r at arbitrary directions.

        Arguments:
            theta_i, phi_i, theta_o, phi_o: angles in radians, broadcastable.
            interpolation: ``"nearest"`` (default) the value of the cell that contains them, as MERL's reference
                code reads it; ``"linear"`` trilinear between the eight nearest cell centres in the cells' own
                coordinates (√θh, θd, and φd periodic with period π), clamped at the first and last centres of θh
                and θd: a continuous function of the directions, what a fit over directions is given.

        Returns:
            f_r in 1/sr, shape ``broadcast(...) + (3,)``; NaN where a cell used is missing, 0 where ωi or ωo lies
            below the horizon (docs/conventions.md).
        """
        from ..geometry import to_half_diff

        if interpolation not in ("nearest", "linear"):
            raise ValueError(f"interpolation must be 'nearest' or 'linear', got {interpolation!r}")
        theta_i, phi_i, theta_o, phi_o = np.broadcast_arrays(*(np.asarray(a, dtype=float)
                                                               for a in (theta_i, phi_i, theta_o, phi_o)))
        th, _, td, pd = (np.asarray(a, dtype=float) for a in jitted(to_half_diff)(theta_i, phi_i, theta_o, phi_o))
        if interpolation == "nearest":
            out = np.moveaxis(self.data[:, theta_h_index(th), theta_d_index(td), phi_d_index(pd)], 0, -1)
        else:
            out = self._trilinear(th, td, pd)
        below = ~((np.cos(theta_i) > 0) & (np.cos(theta_o) > 0))
        return np.where(below[..., None], 0.0, out)

    def _trilinear(self, theta_h, theta_d, phi_d) -> np.ndarray:
        """Trilinear interpolation of the cells at (θh, θd, φd) (`lookup`), shape ``theta_h.shape + (3,)``."""
        # continuous cell coordinates whose integers are the centres (theta_h_centre, theta_d_centre, phi_d_centre)
        x = np.sqrt(np.clip(theta_h, 0.0, _HALF_PI) / _HALF_PI) * DIMS[0] - 0.5
        y = np.asarray(theta_d) / _HALF_PI * DIMS[1] - 0.5
        z = np.mod(np.asarray(phi_d), math.pi) / math.pi * DIMS[2] - 0.5
        i0, fx = grid_patch(x / (DIMS[0] - 1), DIMS[0])  # the centres are the nodes of a regular grid
        j0, fy = grid_patch(y / (DIMS[1] - 1), DIMS[1])
        k0 = np.floor(z).astype(np.intp)
        fz = z - k0
        out = np.zeros(np.shape(theta_h) + (3,))
        for di, wx in ((0, 1 - fx), (1, fx)):
            for dj, wy in ((0, 1 - fy), (1, fy)):
                for dk, wz in ((0, 1 - fz), (1, fz)):
                    cell = self.data[:, i0 + di, j0 + dj, np.mod(k0 + dk, DIMS[2])]
                    out += np.moveaxis(cell, 0, -1) * (wx * wy * wz)[..., None]
        return out

    def to_measurements(self, sampling: str = DEFAULT_SAMPLING, *, pairs: int = DEFAULT_PAIRS, seed: int = 0,
                        max_theta: float = DEFAULT_MAX_THETA, subsample: int | None = None,
                        phi_h: float | None = None) -> Measurements:
        """The table as the samples a fit is given (`brdffit.io.tabulated`).

        Arguments:
            sampling: ``"directions"`` (default) the table's trilinear interpolation (`lookup`) at ``pairs``
                importance-weighted direction pairs with θi, θo ≤ ``max_theta`` (`brdffit.io.tabulated`);
                ``"grid"`` one sample per cell centre weighted by the cell measure (`grid_measurements`, which
                ``subsample`` and ``phi_h`` are for).
            pairs, max_theta: the direction pairs (``"directions"`` only): how many, the largest polar angle in
                radians (80° by default).
            seed: the seed of the pairs' random shift, or of a ``"grid"`` subsample.

        Returns:
            `Measurements`, channels ``("R", "G", "B")``, NaN where a cell is missing.

        Raises:
            ValueError: an unknown sampling, or ``subsample`` / ``phi_h`` with ``"directions"``. MeasurementError:
                no value above the horizon (naming the file).
        """
        check_sampling(sampling, pairs, max_theta)
        if sampling == "grid":
            return self.grid_measurements(subsample=subsample, seed=seed, phi_h=0.0 if phi_h is None else phi_h)
        if subsample is not None or phi_h is not None:
            raise ValueError("subsample and phi_h choose cells of the grid: give them with sampling='grid' (the "
                             "default sampling draws `pairs` direction pairs)")
        try:
            return over_directions(functools.partial(self.lookup, interpolation="linear"), pairs=pairs, seed=seed,
                                   max_theta_i=float(max_theta), max_theta_o=float(max_theta), isotropic=True,
                                   channels=CHANNELS, meta=self._meta()).check_informative()
        except MeasurementError as err:
            raise err.with_file(self.source or "MERL table") from None

    def _meta(self) -> dict:
        """What every reading of the table records: source, format, instrument."""
        return {"source": self.source, "format": "merl", "instrument": "MERL BRDF table (Matusik et al. 2003)"}

    def grid_measurements(self, subsample: int | None = None, seed: int = 0, phi_h: float = 0.0) -> Measurements:
        """The table as `Measurements`: one sample per cell at the cell centre, weighted by the cell measure.

        Arguments:
            subsample: keep this many cells, drawn without replacement with ``seed`` (None keeps all).
            seed: seed of `numpy.random.default_rng`.
            phi_h: the half-vector azimuth of the samples (the table is isotropic; any value will do).

        Returns:
            `Measurements` of the cells with at least one channel present and both directions above the horizon,
            in cell order (θh, θd, φd), channels ``("R", "G", "B")``, ``weights`` the cell measures (sr², not
            rescaled by a subsample).

        Raises:
            MeasurementError: no cell with a value above the horizon, or a channel with no value (naming the file).
        """
        theta_i, phi_i, theta_o, phi_o = (a.reshape(-1) for a in cell_angles(float(phi_h)))
        flat = self.data.reshape(3, -1)
        present = np.isfinite(flat).any(axis=0)
        above = _above_horizon(theta_i, theta_o)
        rows = np.flatnonzero(present & above)
        n_valid = len(rows)
        if subsample is not None:
            if int(subsample) < 1:
                raise ValueError(f"subsample must be a positive number of cells, got {subsample!r}")
            if int(subsample) < len(rows):
                rows = np.sort(np.random.default_rng(seed).choice(rows, size=int(subsample), replace=False))
        meta = {
            **self._meta(),
            "convention": "cell centres in Rusinkiewicz half/difference angles, phi_h = "
                          f"{float(phi_h)!r}; weights = cell measure in (wi, wo) space (docs/formats.md)",
            "cells": {"present_above_horizon": n_valid,
                      "present_below_horizon_dropped": int((present & ~above).sum()),
                      "missing": int((~present).sum())},
        }
        if subsample is not None:
            meta["subsample"] = {"n": int(len(rows)), "seed": int(seed)}
        measurements = Measurements(theta_i[rows], phi_i[rows], theta_o[rows], phi_o[rows], flat[:, rows].T,
                                    weights=cell_weights().reshape(-1)[rows], channels=CHANNELS, meta=meta)
        try:
            return measurements.check_informative()
        except MeasurementError as err:
            raise err.with_file(self.source or "MERL table") from None

    def write(self, path) -> None:
        """Write the table as a MERL binary file (see `write_merl`)."""
        write_merl(self, path)


# ----------------------------------------------------------------------------------------------- read / write
def looks_like_merl(head: bytes) -> bool:
    """Whether the first bytes of a file are a MERL header (int32 90, 90, 180)."""
    return len(head) >= HEADER_BYTES and tuple(np.frombuffer(head[:HEADER_BYTES], dtype="<i4")) == DIMS


def read_merl(path) -> MerlTable:
    """Read a whole MERL binary file.

    Returns:
        `MerlTable` with f_r in 1/sr (scaled per channel), NaN where the file stores a negative number.

    Raises:
        FormatError: a Git LFS pointer, a file shorter than its header, dimensions other than (90, 90, 180), a size
            other than 34,992,012 bytes (truncated or trailing data), or an infinite number.
    """
    path = Path(path)
    data = read_file_bytes(path)
    if len(data) < HEADER_BYTES:
        raise FormatError(path, f"{len(data)} bytes: shorter than the 12-byte MERL header (truncated or not a "
                                "MERL file)")
    dims = tuple(int(d) for d in np.frombuffer(data[:HEADER_BYTES], dtype="<i4"))
    if dims != DIMS:
        raise FormatError(path, f"MERL header dimensions are {dims}, expected {DIMS} (θh, θd, φd); not a MERL "
                                "BRDF table")
    if len(data) != FILE_BYTES:
        problem = "truncated" if len(data) < FILE_BYTES else "trailing data after the tables"
        raise FormatError(path, f"{len(data):,} bytes where a MERL file has {FILE_BYTES:,} (12-byte header + "
                                f"3 x {N_CELLS:,} float64): {problem}")
    raw = np.frombuffer(data, dtype="<f8", offset=HEADER_BYTES).reshape(3, *DIMS).astype(np.float64)
    del data
    if np.isinf(raw).any():
        c, i, j, k = (int(x) for x in np.argwhere(np.isinf(raw))[0])
        raise FormatError(path, f"infinite value in channel {CHANNELS[c]} at cell (θh {i}, θd {j}, φd {k})")
    with np.errstate(invalid="ignore"):
        missing = raw < 0
    raw *= np.asarray(SCALES)[:, None, None, None]
    raw[missing] = np.nan
    return MerlTable(raw, source=str(path))


def write_merl(model_or_table, path) -> None:
    """Write a MERL binary file from a `MerlTable` or by tabulating a brdffit model (`MerlTable.from_model`).

    Missing cells (NaN; for a model, the cells with a direction below the horizon) are stored as −1, the MERL
    marker for "no value", so every MERL reader masks them (tools that clamp negatives see 0). The file is written
    to a temporary file beside ``path`` and renamed into place.
    """
    if isinstance(model_or_table, MerlTable):
        table = model_or_table
    elif hasattr(model_or_table, "lobes") and hasattr(model_or_table, "params"):
        table = MerlTable.from_model(model_or_table)
    else:
        raise TypeError(f"write_merl needs a brdffit Model or a MerlTable, got {type(model_or_table).__name__}")
    raw = table.data / np.asarray(SCALES)[:, None, None, None]
    raw[~np.isfinite(raw)] = MISSING_RAW
    path = Path(path)
    with atomic_path(path, suffix=".binary") as tmp:
        with open(tmp, "wb") as fh:
            fh.write(np.asarray(DIMS, dtype="<i4").tobytes())
            fh.write(raw.astype("<f8").tobytes())
