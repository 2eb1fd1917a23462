r"""RGL-EPFL ``.bsdf`` files: measured BRDFs in the adaptive parameterisation of Dupuy & Jakob.

J. Dupuy and W. Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and Rendering", ACM
Transactions on Graphics 37(6), 2018 (the paper). The reference readers are powitacq (by the authors),
Mitsuba 3's ``measured`` plugin (``src/bsdfs/measured.cpp``, ``include/mitsuba/core/distr_2d.h``) and pbrt-v4's
``MeasuredBxDF`` (``src/pbrt/bxdfs.cpp``, ``PiecewiseLinear2D`` in ``src/pbrt/util/sampling.h``). This module is
written from the paper and from reading them; docs/formats.md describes the same in prose.

**Container** ("tensor_file", little endian): 12 bytes ``tensor_file\0``, two uint8 version numbers (1, 0), a
uint32 field count, then per field a uint16 name length and the name, a uint16 rank, a uint8 type code (`DTYPES`),
a uint64 byte offset and ``rank`` uint64 extents. A field's data are C-ordered at its offset.

**Fields used** (P azimuths φi, T polar angles θi of the incidence; ``theta_i``/``phi_i`` in radians):
``ndf`` and ``sigma`` (2-d tables over the unit square of a direction, below), ``vndf`` (P, T, H, W): the density
of visible microfacet normals per incidence, ``rgb`` (P, T, 3, h, w): the measured values on the regular h x w grid
of the *sample square*, ``jacobian`` (uint8 flag), ``description`` (uint8 text). ``luminance`` (the importance-
sampling density of a renderer) and ``valid`` (a per-node bit mask, undocumented, unused by the reference readers)
are kept but not used.

**Unit squares.** A direction (θ, φ) has coordinates u = (√(θ / (π/2)), (φ + π) / (2π)) (`direction_to_unit`); a
2-d table of shape (rows, columns) is the bilinear interpolant of its nodes on the regular grid of [0, 1]², the
column index along u₁ and the row index along u₂. The microfacet normal m = (ωi + ωo)/|ωi + ωo| is taken in these
coordinates, for an isotropic file (P <= 2) with its azimuth measured from φi.

**The warp** (the paper's parameterisation, inverted). For each incidence the ``vndf`` table, normalised to integrate to
1 over the unit square, is a density p(u); the map from u to the sample square is the continuous marginal /
conditional CDF of its bilinear interpolant: s₂ = F(u₂) = ∫₀^{u₂} r(t) dt with r(t) = ∫₀¹ p(x, t) dx, and
s₁ = ∫₀^{u₁} p(x, u₂) dx / r(u₂). Its Jacobian is triangular with determinant p(u). Between tabulated incidences every
table (the density and both CDFs) is interpolated linearly in θi (and φi), as the reference readers do.

**The value.** ``rgb`` bilinear at s (and linear in θi, φi) times, when ``jacobian`` is set, D(m) / (4 σ(ωi)) with
D = ``ndf`` at u(m) and σ = ``sigma`` at u(ωi): this is f_r · cos θo, what the reference readers return. brdffit
divides by cos θo (docs/conventions.md: f_r without the cosine factor).

**Negative values.** Some films hold small negative rgb values (ringing of the colour fit). pbrt-v4 and powitacq
clip the interpolated value to 0, Mitsuba keeps it: `RglTable.lookup` clips by default (``negative="keep"`` keeps
them), `RglTable.to_measurements` and `RglTable.grid_measurements` clip (``negative="missing"`` makes them NaN);
the counts go to ``meta["read"]``.

**What a fit is given.** `RglTable.to_measurements` by default evaluates `RglTable.lookup` at importance-weighted
quasi-random direction pairs (`brdffit.io.tabulated`: the nodes below sit where the warp puts them, so a fit to them
is not a fit over directions). ``sampling="grid"`` gives the nodes themselves (`RglTable.grid_measurements`).

**Grid samples and weights.** `RglTable.grid_measurements` gives one sample per node of the rgb grid and per
measured incidence: the node s is mapped through the inverse of the warp to u(m), hence m and ωo = 2 (ωi·m) m − ωi. Its
weight is the solid angle it stands for: |dωo / ds| times the node's cell of the sample square by the trapezoid
rule (¼, ½ or 1 times 1/((h−1)(w−1)) at corners, edges, inside). The Jacobian of s -> ωo is

.. math::
    \left|\frac{d\omega_o}{ds}\right| = \frac{4\,(\omega_i\cdot m)\;\cdot\;2\pi^2\,u_1 \sin\theta_m}{p(u)}
    = \frac{4\,\sigma(\omega_i)}{D(m)}

(4 (ωi·m): the reflection ωo(m), Walter et al. 2007 eq. 14; 2π² u₁ sin θm = dωm/du for θm = (π/2) u₁²,
φm = 2π u₂ − π; 1/p(u): the warp). The second form holds because the vndf is the visible normal distribution,
p(u) = (ωi·m) D(m) / σ(ωi) · dωm/du (the files agree to 1 %, tests/test_io_rgl.py). brdffit uses this form:
the bilinear p(u) vanishes linearly at u₁ = 0, where the first form is 0/0 at the nodes of the specular direction
(the whole column s₁ = 0 maps to m = n) and would drop the peak. With it, weight · f_r · cos θo = cell · rgb, so
Σ weight · f_r · cos θo over one incidence is the trapezoid rule for its directional albedo ∫ f_r cos θo dωo.

**Conventions.** ωi is the direction to the light: the incidence of the tables (Mitsuba evaluates the table at its
``si.wi`` and returns the value times the cosine of its ``wo``; pbrt-v4 at its ``wo``, dividing by the cosine of
its ``wi``). At normal incidence the azimuth of ωi is undefined: brdffit uses φi = 0, what ``atan2(0, 0)`` gives
(Mitsuba 3.9 first folds ωi by a rotation by π and gets 0 or −π depending on the signs of the zero components). The
tabulated incidence θi = 90° (a light at the horizon; the files copy the slice before it) is
used for interpolation only, not as samples.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import struct
from pathlib import Path

import numpy as np

from ..measurements import MeasurementError, Measurements
from ._common import FormatError, read_file_bytes
from .tabulated import (DEFAULT_MAX_THETA, DEFAULT_PAIRS, DEFAULT_SAMPLING, check_sampling, grid_patch,
                        over_directions, unit_vectors, vector_angles)

__all__ = ["RglTable", "read_rgl", "read_tensor_file", "looks_like_rgl", "direction_to_unit", "MAGIC", "DTYPES"]

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
HEADER_BYTES = len(MAGIC) + 2 + 4  # magic, version (2 x uint8), field count (uint32)
# The most dimensions a field may declare: NumPy 1's limit on an array's dimensions (NumPy 2 allows 64), far beyond
# the RGL-EPFL files' (their RGB table has 5). A damaged rank, or extent, beside a zero extent would otherwise pass
# the size check (no data) and fail in reshape with NumPy's own message.
MAX_RANK = 32
# The largest extent of an axis (NumPy's intp); a damaged uint64 extent beside a zero one passes the size check too.
_MAX_EXTENT = np.iinfo(np.intp).max
# Type codes of the container and their NumPy types (little endian).
DTYPES = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2", 10: "<f4",
          11: "<f8"}
CHANNELS = ("R", "G", "B")
REQUIRED = ("description", "theta_i", "phi_i", "ndf", "sigma", "vndf", "rgb", "jacobian")
NEGATIVE_LOOKUP = ("clip", "keep", "missing")
NEGATIVE_SAMPLES = ("clip", "missing")

_HALF_PI = math.pi / 2
_TWO_PI = 2 * math.pi


# ----------------------------------------------------------------------------------------------- the container
def looks_like_rgl(head: bytes) -> bool:
    """Whether the first bytes of a file are a tensor_file header (the RGL-EPFL ``.bsdf`` container)."""
    return head[:len(MAGIC)] == MAGIC


class _Cursor:
    """Reads the header of a tensor_file front to back; running out of bytes is a `FormatError`."""

    def __init__(self, path, data: bytes):
        self.path, self.data, self.pos = path, data, 0

    def take(self, fmt: str, what: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise FormatError(self.path, f"truncated: the header ends inside {what} (byte {self.pos} of "
                                         f"{len(self.data)})")
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values


def read_tensor_file(path) -> dict[str, np.ndarray]:
    """Read every field of a tensor_file.

    Arguments:
        path: the file.

    Returns:
        ``{name: array}`` in file order, each a read-only NumPy array of the field's type and shape (native byte
        order).

    Raises:
        FileNotFoundError: no such file. FormatError: a Git LFS pointer, a wrong magic or version, a header that
            ends early, a name that is not UTF-8 or occurs twice, an unknown type code, or a field whose data lie
            outside the file; the message names the file and the field.
    """
    path = Path(path)
    data = read_file_bytes(path)
    if len(data) < len(MAGIC) or data[:len(MAGIC)] != MAGIC:
        if MAGIC.startswith(data):
            raise FormatError(path, f"truncated: {len(data)} bytes, shorter than the {HEADER_BYTES}-byte "
                                    "tensor_file header")
        raise FormatError(path, f"not an RGL-EPFL tensor_file: the file starts with {data[:len(MAGIC)]!r}, "
                                f"expected {MAGIC!r}")
    cursor = _Cursor(path, data)
    cursor.pos = len(MAGIC)
    version = cursor.take("<BB", "the version")
    if version != VERSION:
        raise FormatError(path, f"tensor_file version {version[0]}.{version[1]}; brdffit reads version "
                                f"{VERSION[0]}.{VERSION[1]}")
    (count,) = cursor.take("<I", "the field count")
    fields: dict[str, np.ndarray] = {}
    for index in range(count):
        (name_length,) = cursor.take("<H", f"the name length of field {index + 1} of {count}")
        (raw_name,) = cursor.take(f"<{name_length}s", f"the name of field {index + 1} of {count}")
        try:
            name = raw_name.decode("utf-8")
        except UnicodeDecodeError:
            raise FormatError(path, f"the name of field {index + 1} of {count} is not UTF-8: {raw_name!r}") from None
        where = f"field {name!r}"
        rank, code, offset = cursor.take("<HBQ", f"the rank, type and offset of {where}")
        if rank > MAX_RANK:
            raise FormatError(path, f"{where}: rank {rank}, more than the {MAX_RANK} dimensions brdffit reads (the "
                                    "RGL-EPFL fields have at most 5): damaged")
        shape = cursor.take(f"<{rank}Q", f"the shape of {where}")
        if any(extent > _MAX_EXTENT for extent in shape):
            raise FormatError(path, f"{where}: an extent of {max(shape):,}, more than an array's axis can hold "
                                    f"({_MAX_EXTENT:,}): damaged")
        if code not in DTYPES:
            raise FormatError(path, f"{where}: unknown type code {code} (a tensor_file has codes 1-11: u8, i8, "
                                    "u16, i16, u32, i32, u64, i64, f16, f32, f64)")
        if name in fields:
            raise FormatError(path, f"{where} occurs twice")
        dtype = np.dtype(DTYPES[code])
        n = math.prod(shape)  # a Python integer: no overflow, however large the extents
        if offset + n * dtype.itemsize > len(data):
            extent = f"shape {tuple(shape)}" if rank <= 8 else f"rank {rank}"
            raise FormatError(path, f"{where}: its data ({extent}, {dtype.name}, from byte {offset:,}) lie outside "
                                    f"the file ({len(data):,} bytes): truncated or damaged")
        array = np.frombuffer(data, dtype=dtype, count=n, offset=offset).reshape(shape).astype(dtype.newbyteorder("="))
        array.flags.writeable = False
        fields[name] = array
    return fields


# ---------------------------------------------------------------------------------------------- unit squares
def direction_to_unit(theta, phi) -> tuple[np.ndarray, np.ndarray]:
    """The unit-square coordinates of a direction: u₁ = √(θ / (π/2)), u₂ = (φ + π) / (2π) (φ in [−π, π])."""
    return np.sqrt(np.clip(theta, 0.0, _HALF_PI) / _HALF_PI), (np.asarray(phi) + math.pi) / _TWO_PI


def _bilinear(table: np.ndarray, u1, u2) -> np.ndarray:
    """A 2-d table (rows along u₂, columns along u₁) interpolated bilinearly at (u₁, u₂), clipped to [0, 1]²."""
    i, fx = grid_patch(u1, table.shape[1])
    j, fy = grid_patch(u2, table.shape[0])
    top = table[j, i] + fx * (table[j, i + 1] - table[j, i])
    bottom = table[j + 1, i] + fx * (table[j + 1, i + 1] - table[j + 1, i])
    return top + fy * (bottom - top)


def _segment_inverse(target, width: float, v0, v1) -> np.ndarray:
    """The fraction f in [0, 1] of a segment where ∫₀^f of the linear density v0 -> v1 (segment ``width``) is
    ``target``: the root of width·(v0 f + (v1 − v0) f²/2) = target, in the form without cancellation."""
    c = np.maximum(target, 0.0) / width
    disc = np.sqrt(np.maximum(v0 * v0 + 2.0 * (v1 - v0) * c, 0.0))
    denominator = v0 + disc
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(denominator > 0, 2.0 * c / denominator, 0.0)
    return np.clip(f, 0.0, 1.0)


class _Warp:
    """The vndf warp of a file: per incidence slice, the normalised density and its marginal / conditional CDFs.

    Slices are numbered p·T + t (azimuth index p, polar index t). Every lookup takes ``slices`` (N, K) and
    ``mix`` (N, K): the value is Σₖ mix[:, k] · table[slices[:, k], ...] (linear interpolation in θi and φi).
    """

    def __init__(self, vndf: np.ndarray):
        p_count, t_count, rows, cols = vndf.shape
        self.rows, self.cols = rows, cols
        self.dx, self.dy = 1.0 / (cols - 1), 1.0 / (rows - 1)
        density = vndf.reshape(p_count * t_count, rows, cols).astype(np.float64)
        # the integral of a row's linear interpolant from 0 to each column node (trapezoid = exact for linear)
        cond = np.cumsum(0.5 * self.dx * (density[:, :, 1:] + density[:, :, :-1]), axis=2)
        row_total = cond[:, :, -1]
        marg = np.cumsum(0.5 * self.dy * (row_total[:, 1:] + row_total[:, :-1]), axis=1)
        norm = 1.0 / marg[:, -1]
        self.density = density * norm[:, None, None]
        self.cond = np.concatenate([np.zeros((len(norm), rows, 1)), cond * norm[:, None, None]], axis=2)
        self.row_total = self.cond[:, :, -1]
        self.marg = np.concatenate([np.zeros((len(norm), 1)), marg * norm[:, None]], axis=1)

    @staticmethod
    def _mix(table: np.ndarray, slices, mix, *index) -> np.ndarray:
        return np.einsum("nk,nk->n", mix, table[(slices, *(i[:, None] for i in index))])

    def to_sample(self, u1, u2, slices, mix) -> tuple[np.ndarray, np.ndarray]:
        """The sample-square point (s₁, s₂) of unit-square points u: the marginal / conditional CDFs at u."""
        i, fx = grid_patch(u1, self.cols)
        j, fy = grid_patch(u2, self.rows)
        d = functools.partial(self._mix, self.density, slices, mix)
        c0 = d(j, i) + fy * (d(j + 1, i) - d(j, i))  # density along the row through u₂, at the patch's columns
        c1 = d(j, i + 1) + fy * (d(j + 1, i + 1) - d(j, i + 1))
        cond = functools.partial(self._mix, self.cond, slices, mix)
        before = cond(j, i) + fy * (cond(j + 1, i) - cond(j, i))
        r0 = self._mix(self.row_total, slices, mix, j)
        r1 = self._mix(self.row_total, slices, mix, j + 1)
        row = r0 + fy * (r1 - r0)
        inside = fx * (c0 + 0.5 * fx * (c1 - c0)) * self.dx
        with np.errstate(divide="ignore", invalid="ignore"):
            s1 = np.where(row > 0, (before + inside) / row, 0.0)
        s2 = self._mix(self.marg, slices, mix, j) + fy * (r0 + 0.5 * fy * (r1 - r0)) * self.dy
        return s1, s2

    def from_sample(self, s1, s2, slice_index: int) -> tuple[np.ndarray, np.ndarray]:
        """The unit-square point u of sample-square points (s₁, s₂) in one tabulated slice: the inverse CDFs."""
        marg = self.marg[slice_index]
        j = np.clip(np.searchsorted(marg[1:], s2, side="left"), 0, self.rows - 2)
        r0, r1 = self.row_total[slice_index, j], self.row_total[slice_index, j + 1]
        fy = _segment_inverse(s2 - marg[j], self.dy, r0, r1)
        density, cond = self.density[slice_index], self.cond[slice_index]
        along = density[j] + fy[:, None] * (density[j + 1] - density[j])  # (N, cols): the row through u₂
        cum = cond[j] + fy[:, None] * (cond[j + 1] - cond[j])
        target = s1 * cum[:, -1]
        i = np.clip((cum[:, 1:] < target[:, None]).sum(axis=1), 0, self.cols - 2)
        rows = np.arange(len(i))
        fx = _segment_inverse(target - cum[rows, i], self.dx, along[rows, i], along[rows, i + 1])
        return (i + fx) * self.dx, (j + fy) * self.dy


def _interval_weights(values: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear interpolation in a tabulated parameter: (lower index, weight of lower, weight of upper); clamped at
    the ends, a single value has weight 1."""
    if len(values) == 1:
        zero = np.zeros(x.shape, dtype=np.intp)
        return zero, np.ones(x.shape), np.zeros(x.shape)
    k = np.clip(np.searchsorted(values, x, side="left") - 1, 0, len(values) - 2)
    upper = np.clip((x - values[k]) / (values[k + 1] - values[k]), 0.0, 1.0)
    return k, 1.0 - upper, upper


# ------------------------------------------------------------------------------------------------- the table
@dataclasses.dataclass(frozen=True, eq=False)
class RglTable:
    """The fields of an RGL-EPFL RGB ``.bsdf`` file, as read (module docstring for their meaning).

    Fields:
        theta_i: (T,) polar angles of the tabulated incidences, radians, increasing.
        phi_i: (P,) their azimuths, radians (P = 1 for an isotropic file).
        ndf: (rows, cols) the microfacet distribution D over the unit square of m.
        sigma: (rows, cols) the projected area σ over the unit square of ωi.
        vndf: (P, T, H, W) the visible-normal density per incidence (the warp).
        rgb: (P, T, 3, h, w) the measured values on the sample-square grid.
        jacobian: whether the value carries the factor D / (4 σ).
        luminance: (P, T, h, w) or None: a renderer's sampling density, not used here.
        valid: (h·w,) uint8 or None: a per-node bit mask whose meaning the file does not state; not used here.
        path: the file read, description: the file's ``description`` text.
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    ndf: np.ndarray
    sigma: np.ndarray
    vndf: np.ndarray
    rgb: np.ndarray
    jacobian: bool
    luminance: np.ndarray | None = None
    valid: np.ndarray | None = None
    path: str | None = None
    description: str = ""

    def __repr__(self) -> str:
        return (f"RglTable(path={self.path!r}, description={self.description!r}, incidences={len(self.theta_i)} "
                f"x {len(self.phi_i)}, grid={self.rgb.shape[-2]}x{self.rgb.shape[-1]})")

    @property
    def isotropic(self) -> bool:
        """Whether the file is isotropic (at most two tabulated azimuths, as the reference readers decide)."""
        return len(self.phi_i) <= 2

    @functools.cached_property
    def _warp(self) -> _Warp:
        return _Warp(self.vndf)

    @functools.cached_property
    def _reduction(self) -> int:
        """The symmetry folding of an anisotropic file: its azimuths span 2π / reduction (1, 2 or 4)."""
        if self.isotropic:
            return 1
        return int(round(_TWO_PI / float(self.phi_i[-1] - self.phi_i[0])))

    def _slices(self, theta_i: np.ndarray, phi_i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Slice numbers and interpolation weights, each (N, 4), of incidences (θi, φi)."""
        t, t0, t1 = _interval_weights(self.theta_i, theta_i)
        p, p0, p1 = _interval_weights(self.phi_i, phi_i)
        step_p = len(self.theta_i) if len(self.phi_i) > 1 else 0
        t_up = np.minimum(t + 1, len(self.theta_i) - 1)
        p_up = p + (1 if len(self.phi_i) > 1 else 0)
        slices = np.stack([p * step_p + t, p * step_p + t_up, p_up * step_p + t, p_up * step_p + t_up], axis=1)
        mix = np.stack([p0 * t0, p0 * t1, p1 * t0, p1 * t1], axis=1)
        return slices, mix

    def _microfacets(self, u1, u2, theta_i, phi_i) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """D(m) at unit-square points u(m), σ(ωi), and the value factor: D / (4 σ) when the file sets
        ``jacobian``, else 1."""
        ndf = _bilinear(self.ndf, u1, u2)
        sigma = _bilinear(self.sigma, *direction_to_unit(theta_i, phi_i))
        return ndf, sigma, ndf / (4.0 * sigma) if self.jacobian else np.ones(np.shape(ndf))

    def _rgb_at(self, s1, s2, slices, mix) -> np.ndarray:
        """The rgb grid at sample-square points, interpolated bilinearly in s and linearly in θi, φi: (N, 3)."""
        rgb = self.rgb.reshape(-1, *self.rgb.shape[2:])
        h, w = rgb.shape[-2:]
        i, fx = grid_patch(s1, w)
        j, fy = grid_patch(s2, h)
        out = np.zeros((len(s1), 3))
        for k in range(slices.shape[1]):
            c = functools.partial(_corner, rgb, slices[:, k])
            top = c(j, i) * (1 - fx)[:, None] + c(j, i + 1) * fx[:, None]
            bottom = c(j + 1, i) * (1 - fx)[:, None] + c(j + 1, i + 1) * fx[:, None]
            out += mix[:, k, None] * (top * (1 - fy)[:, None] + bottom * fy[:, None])
        return out

    def lookup(self, theta_i, phi_i, theta_o, phi_o, *, negative: str = "clip") -> np.ndarray:
        """The BRDF f_r at arbitrary direction pairs, evaluated as the reference readers do (module docstring).

        Arguments:
            theta_i, phi_i, theta_o, phi_o: angles in radians (ωi towards the light), broadcastable.
            negative: ``"clip"`` (default) a negative interpolated value becomes 0, as in pbrt-v4 and powitacq;
                ``"keep"`` keeps it, as Mitsuba does; ``"missing"`` makes it NaN.

        Returns:
            f_r in 1/sr (the table's value divided by cos θo), shape ``broadcast(...) + (3,)``; 0 where ωi or ωo
            lies at or below the horizon.
        """
        if negative not in NEGATIVE_LOOKUP:
            raise ValueError(f"negative must be one of {', '.join(NEGATIVE_LOOKUP)}, got {negative!r}")
        arrays = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_i, phi_i, theta_o, phi_o)))
        shape = arrays[0].shape
        ti, pi_, to, po = (a.reshape(-1) for a in arrays)
        wi, wo = unit_vectors(ti, pi_), unit_vectors(to, po)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        wi, wo = wi[above], wo[above]
        if self._reduction >= 2:
            wi, wo = self._fold(wi, wo)
        m = wi + wo
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        theta_in, phi_in = vector_angles(wi)
        theta_m, phi_m = vector_angles(m)
        u_m = direction_to_unit(theta_m, phi_m - phi_in if self.isotropic else phi_m)
        u_m = (u_m[0], u_m[1] - np.floor(u_m[1]))
        slices, mix = self._slices(theta_in, phi_in)
        s1, s2 = self._warp.to_sample(*u_m, slices, mix)
        factor = self._microfacets(*u_m, theta_in, phi_in)[2]
        value = self._rgb_at(s1, s2, slices, mix) * (factor / wo[:, 2])[:, None]
        if negative == "clip":
            value = np.maximum(value, 0.0)
        elif negative == "missing":
            value = np.where(value < 0, np.nan, value)
        out = np.zeros((len(ti), 3))
        out[above] = value
        return out.reshape(*shape, 3)

    def _fold(self, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map ωi into the tabulated azimuth range by the file's symmetry, applying the same map to ωo: a
        rotation by π (reduction 2) or mirrors in x and y (reduction 4), into the half / quadrant of negative
        coordinates, as the reference readers do."""
        sy = np.where(np.signbit(wi[:, 1]), 1.0, -1.0)
        sx = np.where(np.signbit(wi[:, 0]), 1.0, -1.0) if self._reduction == 4 else sy
        flip = np.stack([sx, sy, np.ones_like(sx)], axis=1)
        return wi * flip, wo * flip

    def to_measurements(self, sampling: str = DEFAULT_SAMPLING, *, pairs: int = DEFAULT_PAIRS, seed: int = 0,
                        max_theta: float = DEFAULT_MAX_THETA, negative: str = "clip") -> Measurements:
        """The table as the samples a fit is given (`brdffit.io.tabulated`).

        Arguments:
            sampling: ``"directions"`` (default) the file's interpolation (`lookup`) at ``pairs``
                importance-weighted direction pairs, θi and θo up to ``max_theta`` (`brdffit.io.tabulated`);
                ``"grid"`` the file's own nodes with their solid-angle weights (`grid_measurements`).
            pairs, seed, max_theta: the direction pairs (``"directions"`` only): how many, the seed of their shift,
                the largest polar angle in radians (80° by default).
            negative: ``"clip"`` (default) a negative value becomes 0; ``"missing"`` makes it NaN.

        Returns:
            `Measurements`, channels ``R, G, B``.
        """
        check_sampling(sampling, pairs, max_theta)
        _check_negative_samples(negative)
        if sampling == "grid":
            return self.grid_measurements(negative=negative)
        try:
            return over_directions(
                functools.partial(self.lookup, negative=negative), pairs=pairs, seed=seed,
                max_theta_i=float(max_theta), max_theta_o=float(max_theta),
                isotropic=self.isotropic, channels=CHANNELS, meta=self._meta()).check_informative()
        except MeasurementError as err:
            raise err.with_file(self.path) from None

    def _meta(self) -> dict:
        """What every reading of the file records: source, format, description, instrument."""
        return {"source": self.path, "format": "rgl", "description": self.description,
                "instrument": "RGL-EPFL adaptive-parameterisation gonio-photometer (Dupuy & Jakob 2018)"}

    def grid_measurements(self, *, negative: str = "clip") -> Measurements:
        """One sample per node of the rgb grid and per measured incidence, weighted by its solid angle.

        Arguments:
            negative: ``"clip"`` (default) a negative node value becomes 0; ``"missing"`` makes it NaN
                (`Measurements` hold f_r >= 0, so negative values cannot be kept).

        Returns:
            `Measurements` in file order (incidence, then node row, then node column), channels ``R, G, B``,
            ``weights`` the solid angle each node stands for (module docstring), so that Σ weight · f_r · cos θo
            over an incidence is the trapezoid rule for its directional albedo. Nodes whose outgoing direction
            lies at or below the horizon are dropped, and so is the incidence θi = 90°; ``meta["read"]`` counts
            them.
        """
        _check_negative_samples(negative)
        h, w = self.rgb.shape[-2:]
        s2, s1 = (a.reshape(-1) for a in np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij"))
        cell = np.outer(_trapezoid(h), _trapezoid(w)).reshape(-1) / ((h - 1) * (w - 1))
        parts = []
        counts = {"below": 0, "no microfacets": 0, "negative": 0, "horizon": 0}
        for p, phi in enumerate(self.phi_i):
            for t, theta in enumerate(self.theta_i):
                if theta >= _HALF_PI - 1e-6:  # π/2 in float32
                    counts["horizon"] += 1
                    continue
                nodes = self._nodes(p * len(self.theta_i) + t, theta, phi, s1, s2, cell)
                above = nodes["wo"][:, 2] > 0
                finite = np.isfinite(nodes["weights"])
                counts["below"] += int((~above).sum())
                counts["no microfacets"] += int((above & ~finite).sum())
                keep = above & finite
                values = nodes["values"][keep]
                negative_mask = values < 0
                counts["negative"] += int(negative_mask.sum())
                theta_o, phi_o = vector_angles(nodes["wo"][keep])
                parts.append((np.full(len(theta_o), theta), np.full(len(theta_o), phi), theta_o, phi_o,
                              np.where(negative_mask, 0.0 if negative == "clip" else np.nan, values),
                              nodes["weights"][keep]))
        theta_i, phi_i, theta_o, phi_o, values, weights = (np.concatenate(column) for column in zip(*parts))
        meta = {
            **self._meta(),
            "convention": "one sample per rgb grid node mapped through the vndf warp; weights = solid angle of the "
                          "node (trapezoid rule in the sample square times |d omega_o / ds| = 4 sigma / D); "
                          "phi_i = 0 at normal incidence (docs/formats.md)",
            "read": {
                "incidences": int(len(self.theta_i) * len(self.phi_i) - counts["horizon"]),
                "incidences at the horizon (theta_i = 90 deg, interpolation only) dropped": counts["horizon"],
                "nodes per incidence": h * w,
                "nodes dropped (outgoing direction at or below the horizon)": counts["below"],
                "nodes dropped (ndf = 0 there: no finite solid angle)": counts["no microfacets"],
                ("negative values clipped to 0" if negative == "clip" else "negative values read as missing"):
                    counts["negative"],
                "weights total": float(weights.sum()),
            },
        }
        try:
            return Measurements(theta_i, phi_i, theta_o, phi_o, values, weights=weights, channels=CHANNELS,
                                meta=meta).check_informative()
        except MeasurementError as err:
            raise err.with_file(self.path) from None

    def _nodes(self, slice_index: int, theta: float, phi: float, s1, s2, cell) -> dict[str, np.ndarray]:
        """Outgoing directions ωo (N, 3) (some may lie below the horizon), values f_r (N, 3), unclipped, and
        weights (module docstring) of sample-square points of one tabulated incidence."""
        u1, u2 = self._warp.from_sample(s1, s2, slice_index)
        m = unit_vectors(_HALF_PI * u1 * u1, _TWO_PI * u2 - math.pi + (phi if self.isotropic else 0.0))
        wi = unit_vectors(np.array([theta]), np.array([phi]))[0]
        wo = 2.0 * (m @ wi)[:, None] * m - wi
        slices, mix = np.full((len(s1), 1), slice_index), np.ones((len(s1), 1))
        ndf, sigma, factor = self._microfacets(u1, u2, theta, phi)
        with np.errstate(divide="ignore", invalid="ignore"):
            values = self._rgb_at(s1, s2, slices, mix) * (factor / wo[:, 2])[:, None]
            weights = np.where(ndf > 0, cell * 4.0 * sigma / ndf, np.inf)  # |dωo/ds| = 4 σ(ωi) / D(m)
        return {"wo": wo, "values": values, "weights": weights}


def _check_negative_samples(negative: str) -> None:
    """Refuse a ``negative`` option that samples cannot hold."""
    if negative not in NEGATIVE_SAMPLES:
        raise ValueError(f"negative must be one of {', '.join(NEGATIVE_SAMPLES)} (Measurements hold f_r >= 0; "
                         f"RglTable.lookup(..., negative='keep') gives the raw values), got {negative!r}")


def _corner(rgb: np.ndarray, slices: np.ndarray, j: np.ndarray, i: np.ndarray) -> np.ndarray:
    """The three channels of grid node (row j, column i) in each point's slice: (N, 3)."""
    return rgb[slices, :, j, i]


def _trapezoid(n: int) -> np.ndarray:
    """Trapezoid-rule weights of n nodes in units of the spacing: ½, 1, ..., 1, ½."""
    w = np.ones(n)
    w[[0, -1]] = 0.5
    return w


# ----------------------------------------------------------------------------------------------------- reading
def read_rgl(path) -> RglTable:
    """Read an RGL-EPFL RGB ``.bsdf`` file.

    Arguments:
        path: the file (e.g. ``paper_white_rgb.bsdf`` from the RGL-EPFL material database).

    Returns:
        `RglTable` with the file's fields as float64 arrays (read-only).

    Raises:
        FileNotFoundError: no such file. FormatError: a damaged container (`read_tensor_file`), a spectral file,
            a missing field, a field of the wrong type, rank or shape, non-finite numbers, θi not increasing or
            none below 90°, a ``sigma`` <= 0, a negative ``ndf`` or ``vndf``, or an incidence whose ``vndf`` is
            nowhere positive; the message names file and field.
    """
    path = Path(path)
    fields = read_tensor_file(path)
    if "spectra" in fields or "wavelengths" in fields:
        raise FormatError(path, "a spectral RGL-EPFL file (fields 'spectra', 'wavelengths'); brdffit reads the RGB "
                                "files (*_rgb.bsdf, field 'rgb')")
    missing = [name for name in REQUIRED if name not in fields]
    if missing:
        raise FormatError(path, f"missing field(s) {', '.join(repr(n) for n in missing)} (an RGL-EPFL RGB file has "
                                f"{', '.join(REQUIRED)})")
    check = functools.partial(_checked, path, fields)
    theta_i, phi_i = check("theta_i", rank=1), check("phi_i", rank=1)
    t_count, p_count = len(theta_i), len(phi_i)
    ndf, sigma = check("ndf", rank=2, least=2), check("sigma", rank=2, least=2)
    vndf = check("vndf", rank=4, least=2)
    rgb = check("rgb", rank=5, least=2)
    if vndf.shape[:2] != (p_count, t_count):
        raise FormatError(path, f"field 'vndf': shape {vndf.shape} should start with (phi_i, theta_i) = "
                                f"({p_count}, {t_count})")
    if rgb.shape[:3] != (p_count, t_count, 3):
        raise FormatError(path, f"field 'rgb': shape {rgb.shape} should start with (phi_i, theta_i, 3) = "
                                f"({p_count}, {t_count}, 3)")
    if t_count < 1 or p_count < 1:
        raise FormatError(path, f"fields 'theta_i' and 'phi_i' need at least one value, have {t_count} and "
                                f"{p_count}")
    if np.any(np.diff(theta_i) <= 0) or np.any(np.diff(phi_i) <= 0):
        raise FormatError(path, "fields 'theta_i' and 'phi_i' must be strictly increasing")
    if theta_i[0] < 0 or theta_i[-1] > _HALF_PI + 1e-6:
        raise FormatError(path, f"field 'theta_i': angles {theta_i[0]:.6g} .. {theta_i[-1]:.6g} rad lie outside "
                                "[0, π/2]")
    if p_count > 2 and round(_TWO_PI / float(phi_i[-1] - phi_i[0])) not in (1, 2, 4):
        raise FormatError(path, f"field 'phi_i': an anisotropic file spans 2π, π or π/2, this one "
                                f"{float(phi_i[-1] - phi_i[0]):.6g} rad")
    if not theta_i[0] < _HALF_PI - 1e-6:
        raise FormatError(path, "field 'theta_i': no incidence below 90° (nothing was measured)")
    if np.any(sigma <= 0):
        raise FormatError(path, "field 'sigma': the projected area must be > 0 everywhere")
    if np.any(ndf < 0):
        raise FormatError(path, "field 'ndf': a microfacet density must be >= 0")
    if np.any(vndf < 0):
        raise FormatError(path, "field 'vndf': a density must be >= 0")
    empty = np.flatnonzero(vndf.reshape(p_count * t_count, -1).max(axis=1) <= 0)
    if len(empty):
        raise FormatError(path, f"field 'vndf': incidence slice {int(empty[0])} is zero everywhere")
    jacobian = fields["jacobian"]
    if jacobian.dtype.kind not in "ui" or jacobian.size != 1:
        raise FormatError(path, f"field 'jacobian': expected one integer flag, got {jacobian.size} value(s) of "
                                f"type {jacobian.dtype.name}")
    description = fields["description"]
    if description.ndim != 1 or description.dtype.itemsize != 1:
        raise FormatError(path, "field 'description': expected 1-d text bytes (uint8)")
    luminance = check("luminance", rank=4) if "luminance" in fields else None
    valid = np.array(fields["valid"]) if "valid" in fields else None
    return RglTable(theta_i=theta_i, phi_i=phi_i, ndf=ndf, sigma=sigma, vndf=vndf, rgb=rgb,
                    jacobian=bool(int(jacobian.reshape(-1)[0])), luminance=luminance, valid=valid, path=str(path),
                    description=description.tobytes().decode("utf-8", errors="replace"))


def _checked(path, fields: dict, name: str, *, rank: int, least: int = 0) -> np.ndarray:
    """A floating-point field of the given rank, its last two extents >= ``least``, finite, as float64."""
    array = fields[name]
    if array.dtype.kind != "f":
        raise FormatError(path, f"field {name!r}: type {array.dtype.name}, expected floating point (f16/f32/f64)")
    if array.ndim != rank:
        raise FormatError(path, f"field {name!r}: rank {array.ndim} (shape {array.shape}), expected rank {rank}")
    if least and min(array.shape[-2:]) < least:
        raise FormatError(path, f"field {name!r}: shape {array.shape}, a grid needs at least {least} x {least} nodes")
    if not np.all(np.isfinite(array)):
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(array))[0])
        raise FormatError(path, f"field {name!r}: non-finite value {array[index]!r} at index {index}")
    out = array.astype(np.float64)
    out.flags.writeable = False
    return out
