"""The measurement type: BRDF samples at pairs of directions, validated once on construction.

A `Measurements` holds N samples of a BRDF with C channels, in the library's convention (docs/conventions.md):
angles in radians, θ the polar angle from the normal (0 <= θ <= π/2), φ the azimuth from the tangent wrapped into
[0, 2π), ωi towards the light and ωo towards the detector, values f_r in 1/sr without the cosine factor.

Every field is a read-only NumPy float64 array on the host; the maths (fits, metrics) converts to JAX arrays where
it needs them. Missing values are NaN and are kept out of fits; `valid` is their complement.

Readers in `brdffit.io` turn files into this type; a wrong file gives `brdffit.io.FormatError`, a file whose
numbers break the rules below gives `MeasurementError` naming the file, the field, the row and what was expected.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

__all__ = ["Measurements", "MeasurementError", "concatenate"]

# A polar angle may exceed π/2 (or fall below 0) by this much through rounding (a file written in degrees, a
# direction computed from a vector); it is then clipped to the range. Anything further out is an error.
THETA_TOLERANCE = 1e-9
# The largest f_r accepted (1/sr). No surface comes near it (a mirror seen by a detector of 1e-6 sr reads about
# 1e6); the bound keeps squared, weighted residuals finite in float64, so one absurd value (1e300) is refused as
# input instead of ending a fit as "non-finite".
MAX_VALUE = 1e100

_TWO_PI = 2.0 * math.pi
_ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


class MeasurementError(ValueError):
    """Measurements that break a rule: the message names the field, the row and what was expected.

    Attributes:
        field: the offending field (``"theta_i"``, ``"values"``, ...).
        row: the sample index (0-based), or the 1-based file line when ``row_is_line``; None when the whole field
            is wrong.
        expected: what the field should have been.
        file: the file the measurements came from, when known.
        channel: the channel index for errors in ``values`` or ``sigma``.
    """

    def __init__(self, field: str, row: int | None, expected: str, detail: str = "", file: str | None = None,
                 column: str | None = None, row_is_line: bool = False, channel: int | None = None):
        self.field, self.row, self.expected, self.detail = field, row, expected, detail
        self.file, self.column, self.row_is_line, self.channel = file, column, row_is_line, channel
        super().__init__(self._message())

    def __reduce__(self):
        return (MeasurementError, (self.field, self.row, self.expected, self.detail, self.file, self.column,
                                   self.row_is_line, self.channel))

    def _message(self) -> str:
        where = f"{self.file}: " if self.file else ""
        if self.row is not None:
            where += f"line {self.row}: " if self.row_is_line else f"row {self.row}: "
        what = self.field + (f" (column {self.column!r})" if self.column else "")
        detail = f" {self.detail}" if self.detail else ""
        return f"{where}{what}:{detail} expected {self.expected}"

    def with_file(self, file, row_to_line=None, column: str | None = None) -> "MeasurementError":
        """A copy of this error that names ``file``; ``row_to_line`` maps the sample row to a (1-based) file line."""
        row, is_line = self.row, self.row_is_line
        if row is not None and row_to_line is not None:
            row, is_line = int(row_to_line[row]), True
        return MeasurementError(self.field, row, self.expected, self.detail, str(file), column or self.column, is_line,
                                self.channel)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _normalise_meta(meta) -> dict:
    if meta is None:
        return {}
    if not isinstance(meta, dict):
        raise MeasurementError("meta", None, "a dict (JSON-serialisable)", f"got {type(meta).__name__};")
    try:
        text = json.dumps(meta, default=_json_default, allow_nan=True)
    except (TypeError, ValueError) as err:
        raise MeasurementError("meta", None, "a JSON-serialisable dict (str keys; numbers, strings, lists, dicts)",
                               f"{err};") from None
    return json.loads(text)


def _first_bad(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _as_float_array(name: str, x) -> np.ndarray:
    try:
        arr = np.array(x, dtype=np.float64)  # a copy: the caller's array is never aliased or frozen
    except (TypeError, ValueError) as err:
        raise MeasurementError(name, None, "an array of real numbers", f"{err};") from None
    return arr


def _angle(name: str, x, n: int) -> np.ndarray:
    arr = _as_float_array(name, x)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.ndim != 1 or arr.shape[0] != n:
        raise MeasurementError(name, None, f"shape ({n},) to match values", f"got shape {arr.shape};")
    bad = ~np.isfinite(arr)
    if bad.any():
        (row,) = _first_bad(bad)
        raise MeasurementError(name, row, "a finite angle in radians", f"got {float(arr[row])!r};")
    if name.startswith("theta"):
        bad = (arr < -THETA_TOLERANCE) | (arr > math.pi / 2 + THETA_TOLERANCE)
        if bad.any():
            (row,) = _first_bad(bad)
            raise MeasurementError(name, row, "0 <= theta <= pi/2 (radians; a direction above the surface)",
                                   f"got {float(arr[row])!r} rad ({math.degrees(arr[row]):.6g} deg);")
        arr = np.clip(arr, 0.0, math.pi / 2)
    else:
        arr = np.mod(arr, _TWO_PI)
        arr[arr >= _TWO_PI] = 0.0  # np.mod(-tiny, 2π) rounds to 2π
    return arr


def _default_channels(c: int) -> tuple[str, ...]:
    return ("R", "G", "B") if c == 3 else tuple(f"c{k}" for k in range(c))


class Measurements:
    """BRDF samples: N direction pairs, C channels, optional σ and quadrature weights, free-form metadata.

    Immutable: the arrays are read-only copies; `replace` and the selection helpers return new objects.

    Arguments:
        theta_i, phi_i: polar angle and azimuth of the direction to the light (radians), shape ``(N,)`` (a scalar
            is broadcast to N). 0 <= θ <= π/2 (rounding up to 1e-9 rad outside is clipped); φ is wrapped into
            [0, 2π).
        theta_o, phi_o: the same for the direction to the detector.
        values: f_r in 1/sr, shape ``(N, C)``; a 1-d array is one channel ``(N, 1)``. NaN marks a missing value;
            ±inf and negative values are rejected (readers that know a negative means "missing" map it to NaN).
        sigma: per-value standard deviation, shape ``(N, C)``; a scalar or an ``(N,)`` array is broadcast across
            channels. Finite and > 0 wherever the value is present; NaN allowed where the value is missing.
        weights: quadrature weight of each sample, shape ``(N,)``: the solid-angle measure it stands for (1 for
            scattered samples, the cell measure for MERL cells). Finite and >= 0.
        channels: one name per channel (unique strings); default ``("R", "G", "B")`` for 3 channels, else
            ``("c0", "c1", ...)``.
        meta: a JSON-serialisable dict (source file, instrument, conventions, ``"truth"`` for synthetic data). It
            is stored as a normalised copy (tuples become lists, NumPy scalars plain numbers).

    Raises:
        MeasurementError: naming the field, the first offending row and what was expected.
    """

    __slots__ = ("theta_i", "phi_i", "theta_o", "phi_o", "values", "sigma", "weights", "channels", "meta")

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    values: np.ndarray
    sigma: np.ndarray | None
    weights: np.ndarray | None
    channels: tuple[str, ...]
    meta: dict

    def __init__(self, theta_i, phi_i, theta_o, phi_o, values, sigma=None, weights=None, channels=None, meta=None):
        values = _as_float_array("values", values)
        if values.ndim == 1:
            values = values[:, None]
        if values.ndim != 2 or values.shape[1] < 1:
            raise MeasurementError("values", None, "shape (N, C) with C >= 1 (or (N,) for one channel)",
                                   f"got shape {values.shape};")
        n, c = values.shape
        if np.isinf(values).any():
            row, col = _first_bad(np.isinf(values))
            raise MeasurementError("values", row, "a finite value in 1/sr or NaN for missing",
                                   f"channel {col} is {float(values[row, col])!r};", channel=col)
        huge = values > MAX_VALUE  # NaN compares False
        if huge.any():
            row, col = _first_bad(huge)
            raise MeasurementError("values", row, f"f_r <= {MAX_VALUE:g} 1/sr (a physical BRDF value)",
                                   f"channel {col} is {float(values[row, col])!r};", channel=col)
        negative = values < 0  # NaN compares False
        if negative.any():
            row, col = _first_bad(negative)
            raise MeasurementError("values", row, "f_r >= 0 (NaN marks a missing value)",
                                   f"channel {col} is {float(values[row, col])!r};", channel=col)

        angles = {name: _angle(name, x, n) for name, x in zip(_ANGLES, (theta_i, phi_i, theta_o, phi_o))}

        if sigma is not None:
            sigma = _as_float_array("sigma", sigma)
            if sigma.ndim == 1 and sigma.shape[0] == n:
                sigma = sigma[:, None]
            try:
                sigma = np.array(np.broadcast_to(sigma, (n, c)))
            except ValueError:
                raise MeasurementError("sigma", None, f"shape ({n}, {c}) like values (or a scalar, or ({n},))",
                                       f"got shape {sigma.shape};") from None
            present = ~np.isnan(values)
            bad = present & ~(np.isfinite(sigma) & (sigma > 0))
            if bad.any():
                row, col = _first_bad(bad)
                raise MeasurementError("sigma", row, "a finite sigma > 0 where the value is present",
                                       f"channel {col} is {float(sigma[row, col])!r};", channel=col)
            bad = ~present & ~np.isnan(sigma) & ~(np.isfinite(sigma) & (sigma > 0))
            if bad.any():
                row, col = _first_bad(bad)
                raise MeasurementError("sigma", row, "a finite sigma > 0, or NaN where the value is missing",
                                       f"channel {col} is {float(sigma[row, col])!r};", channel=col)

        if weights is not None:
            weights = _as_float_array("weights", weights)
            if weights.ndim == 0:
                weights = np.full(n, float(weights))
            if weights.shape != (n,):
                raise MeasurementError("weights", None, f"shape ({n},)", f"got shape {weights.shape};")
            bad = ~(np.isfinite(weights) & (weights >= 0))
            if bad.any():
                (row,) = _first_bad(bad)
                raise MeasurementError("weights", row, "a finite weight >= 0", f"got {float(weights[row])!r};")

        if channels is None:
            channels = _default_channels(c)
        elif isinstance(channels, str):
            channels = (channels,)
        channels = tuple(channels)
        if len(channels) != c or not all(isinstance(name, str) and name for name in channels):
            raise MeasurementError("channels", None, f"{c} non-empty channel names (one per column of values)",
                                   f"got {channels!r};")
        if len(set(channels)) != c:
            raise MeasurementError("channels", None, "unique channel names", f"got {channels!r};")

        meta = _normalise_meta(meta)

        for name, arr in (*angles.items(), ("values", values), ("sigma", sigma), ("weights", weights)):
            if arr is not None:
                arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "meta", meta)

    def __setattr__(self, name, value):
        raise AttributeError(f"Measurements are immutable; use .replace({name}=...) to get a changed copy")

    def __delattr__(self, name):
        raise AttributeError("Measurements are immutable")

    def __reduce__(self):
        return (_rebuild, (self.fields(),))

    # ----------------------------------------------------------------------------------------------- properties
    @property
    def n(self) -> int:
        """The number of samples N."""
        return int(self.values.shape[0])

    @property
    def n_channels(self) -> int:
        """The number of channels C."""
        return int(self.values.shape[1])

    @property
    def valid(self) -> np.ndarray:
        """``(N, C)`` bool: True where a value is present (finite)."""
        return np.isfinite(self.values)

    def __len__(self) -> int:
        return self.n

    def fields(self) -> dict[str, Any]:
        """The constructor arguments of this object, as a dict (arrays are the read-only originals)."""
        return {name: getattr(self, name) for name in self.__slots__}

    def check_informative(self) -> "Measurements":
        """Refuse measurements that hold no information for a fit: no sample, every weight 0, or a channel with no
        present value of positive weight (a fit of them would end "converged" at its start, with negative degrees
        of freedom). Every reader calls this on what it read; call it on measurements built by hand before a fit.

        Returns:
            ``self``.

        Raises:
            MeasurementError: naming the field and, for an empty channel, the channel.
        """
        if self.n == 0:
            raise MeasurementError("values", None, "at least one sample", "no valid samples: there are none;")
        weighted = np.ones(self.n, dtype=bool) if self.weights is None else self.weights > 0
        if not weighted.any():
            raise MeasurementError("weights", None, "at least one weight > 0", "no valid samples: every weight is 0;")
        informative = self.valid & weighted[:, None]
        if not informative.any():
            raise MeasurementError("values", None, "at least one present value (not NaN) of weight > 0",
                                   "no valid samples: every value is missing (NaN) or has weight 0;")
        empty = np.flatnonzero(~informative.any(axis=0))
        if empty.size:
            k = int(empty[0])
            raise MeasurementError("values", None, "at least one present value (not NaN) of weight > 0 in every "
                                   "channel", f"channel {self.channels[k]!r} has none;", channel=k)
        return self

    def wi(self) -> np.ndarray:
        """Unit vectors towards the light, shape ``(N, 3)`` (NumPy float64)."""
        return _unit(self.theta_i, self.phi_i)

    def wo(self) -> np.ndarray:
        """Unit vectors towards the detector, shape ``(N, 3)`` (NumPy float64)."""
        return _unit(self.theta_o, self.phi_o)

    def __repr__(self) -> str:
        extras = []
        if self.sigma is not None:
            extras.append("sigma")
        if self.weights is not None:
            extras.append("weights")
        missing = int((~self.valid).sum())
        source = self.meta.get("source")
        text = f"Measurements(n={self.n}, channels={self.channels!r}"
        if missing:
            text += f", missing={missing}"
        if extras:
            text += f", with={'+'.join(extras)}"
        if source:
            text += f", source={source!r}"
        return text + ")"

    # -------------------------------------------------------------------------------------------------- copies
    def replace(self, **fields) -> "Measurements":
        """A copy with some constructor arguments replaced (validated again).

        Example: ``m.replace(sigma=None)``, ``m.replace(meta={**m.meta, "note": "cleaned"})``.
        """
        unknown = set(fields) - set(self.__slots__)
        if unknown:
            raise TypeError(f"Measurements has no field {sorted(unknown)[0]!r}; fields: {', '.join(self.__slots__)}")
        return Measurements(**{**self.fields(), **fields})

    def take(self, rows) -> "Measurements":
        """The samples at ``rows`` (an index array or a boolean mask of length N), in that order."""
        rows = np.asarray(rows)
        if rows.dtype == bool:
            if rows.shape != (self.n,):
                raise ValueError(f"a boolean row mask must have shape ({self.n},), got {rows.shape}")
            rows = np.flatnonzero(rows)
        rows = rows.astype(np.intp, copy=False)

        def pick(a):
            return None if a is None else a[rows]

        return Measurements(
            pick(self.theta_i), pick(self.phi_i), pick(self.theta_o), pick(self.phi_o), pick(self.values),
            sigma=pick(self.sigma), weights=pick(self.weights), channels=self.channels, meta=self.meta)

    def select_channels(self, names_or_indices) -> "Measurements":
        """The listed channels only, in the order given.

        Arguments:
            names_or_indices: a channel name or index, or a sequence of them (names and indices may be mixed).
        """
        if isinstance(names_or_indices, (str, int, np.integer)):
            names_or_indices = [names_or_indices]
        cols = []
        for key in names_or_indices:
            if isinstance(key, str):
                if key not in self.channels:
                    raise KeyError(f"no channel {key!r}; channels are {', '.join(self.channels)}")
                cols.append(self.channels.index(key))
            elif isinstance(key, (int, np.integer)) and -self.n_channels <= int(key) < self.n_channels:
                cols.append(int(key) % self.n_channels)
            else:
                raise KeyError(f"no channel {key!r}; use a name from {self.channels!r} or an index "
                               f"below {self.n_channels}")
        if not cols:
            raise ValueError("select_channels needs at least one channel")
        return self.replace(values=self.values[:, cols],
                            sigma=None if self.sigma is None else self.sigma[:, cols],
                            channels=tuple(self.channels[k] for k in cols))

    def select_angles(self, max_theta_i=None, max_theta_o=None, min_theta_i=None, min_theta_o=None,
                      degrees: bool = False) -> "Measurements":
        """The samples whose polar angles lie in the given (inclusive) ranges, e.g. ``max_theta_o=np.radians(80)``.

        Arguments:
            max_theta_i, max_theta_o, min_theta_i, min_theta_o: bounds (radians, or degrees with
                ``degrees=True``); None leaves that side open.
            degrees: whether the bounds are in degrees.
        """
        convert = math.radians if degrees else float
        keep = np.ones(self.n, dtype=bool)
        for bound, arr, upper in ((max_theta_i, self.theta_i, True), (max_theta_o, self.theta_o, True),
                                  (min_theta_i, self.theta_i, False), (min_theta_o, self.theta_o, False)):
            if bound is not None:
                b = convert(bound)
                keep &= (arr <= b) if upper else (arr >= b)
        return self.take(keep)

    def subsample(self, n: int, seed: int = 0, stratified: bool = False) -> "Measurements":
        """``n`` samples drawn without replacement, reproducibly, kept in their original order.

        Arguments:
            n: how many samples to keep; n >= N returns all samples.
            seed: seed of `numpy.random.default_rng`.
            stratified: draw from strata of (θi, θo) in proportion to their sizes (largest remainder), so that every
                incidence angle of a gonio scan keeps its share. The strata are the distinct θi values (or 8
                equal-count θi bins when there are more than 32 distinct values) crossed with 4 equal-count θo bins.
        """
        rows = self.subsample_rows(n, seed, stratified)
        return self if rows is None else self.take(rows)

    def subsample_rows(self, n: int, seed: int = 0, stratified: bool = False) -> np.ndarray | None:
        """The sorted rows that `subsample` keeps (same arguments), or None where it keeps every sample."""
        n = int(n)
        if n < 1:
            raise ValueError(f"subsample needs n >= 1, got {n}")
        if n >= self.n:
            return None
        rng = np.random.default_rng(seed)
        if not stratified:
            return np.sort(rng.choice(self.n, size=n, replace=False))
        strata = _strata(self.theta_i, self.theta_o)
        labels, counts = np.unique(strata, return_counts=True)
        quota = counts * (n / self.n)
        take = np.floor(quota).astype(int)
        remainder = n - int(take.sum())
        if remainder:
            take[np.argsort(-(quota - take), kind="stable")[:remainder]] += 1
        rows = [rng.choice(np.flatnonzero(strata == label), size=k, replace=False)
                for label, k in zip(labels, take) if k]
        return np.sort(np.concatenate(rows))

    def split(self, test_fraction: float = 0.2, seed: int = 0) -> tuple["Measurements", "Measurements"]:
        """A random train / held-out split, reproducible for a seed; each part keeps the original order.

        Returns:
            ``(train, test)`` with ``round(test_fraction * N)`` test samples (at least 1 and at most N - 1).
        """
        if not 0.0 < float(test_fraction) < 1.0:
            raise ValueError(f"test_fraction must lie strictly between 0 and 1, got {test_fraction!r}")
        if self.n < 2:
            raise ValueError(f"cannot split {self.n} sample(s) into a training and a test set")
        n_test = min(max(int(round(test_fraction * self.n)), 1), self.n - 1)
        order = np.random.default_rng(seed).permutation(self.n)
        test = np.zeros(self.n, dtype=bool)
        test[order[:n_test]] = True
        return self.take(~test), self.take(test)


def _rebuild(fields):
    return Measurements(**fields)


def _unit(theta, phi) -> np.ndarray:
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def _bins(x: np.ndarray, n_bins: int, max_distinct: int) -> np.ndarray:
    distinct, inverse = np.unique(x, return_inverse=True)
    if len(distinct) <= max_distinct:
        return inverse
    edges = np.quantile(x, np.linspace(0, 1, n_bins + 1)[1:-1])
    return np.searchsorted(edges, x, side="right")


def _strata(theta_i: np.ndarray, theta_o: np.ndarray) -> np.ndarray:
    return _bins(theta_i, 8, 32) * 8 + _bins(theta_o, 4, 4)


def concatenate(parts: Sequence[Measurements] | Iterable[Measurements]) -> Measurements:
    """Join measurements with the same channels (σ and weights kept only if every part has them; meta of the first)."""
    parts = list(parts)
    if not parts:
        raise ValueError("concatenate needs at least one Measurements")
    first = parts[0]
    for p in parts[1:]:
        if p.channels != first.channels:
            raise ValueError(f"cannot join channels {p.channels!r} to {first.channels!r}")

    def join(name):
        arrays = [getattr(p, name) for p in parts]
        return None if any(a is None for a in arrays) else np.concatenate(arrays)

    return Measurements(*(join(k) for k in (*_ANGLES, "values")), sigma=join("sigma"), weights=join("weights"),
                        channels=first.channels, meta=first.meta)
