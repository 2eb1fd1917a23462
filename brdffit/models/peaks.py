"""Where a lobe peaks: the declaration each lobe makes of its highlights (`Lobe.peaks`).

A peak says how to draw an outgoing direction ωo for a given ωi so that it lands where the lobe is large. The
export's deviation measure draws pairs at every peak of a source model and of what a renderer writes for it
(`brdffit.export.terms.deviation_pairs`): uniform pairs alone miss a sharp highlight, which is where a renderer's
approximation of a lobe differs most.
"""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module

np = module("numpy")  # loaded on first use: the registry (`brdffit models`) does not need NumPy

__all__ = ["Peak", "MIRROR", "power_width", "scalar"]

# The axis A of a cone about the mirror direction: normalize(A ωi) = (−ωx, −ωy, ωz).
MIRROR = (-1.0, -1.0, 1.0)


@dataclasses.dataclass(frozen=True)
class Peak:
    """Where a lobe peaks, as a way of drawing ωo for a given ωi.

    Attributes:
        kind: ``"half"``: the half vector h is drawn about the normal from a GGX distribution of width ``width``
            (density D(h) cosθh) and ωo = 2 (ωi·h) h − ωi, which puts ωo near the mirror direction for every
            half-vector lobe (microfacet, Ward, Blinn-Phong, Ashikhmin-Shirley). ``"cone"``: ωo is drawn about the
            axis d = normalize(A ωi) with the same GGX density in the angle from d: A = (−1, −1, 1) is the mirror
            direction (Phong, toon highlight), (1, 1, 1) the back-scattering direction ωo = ωi (a retro-reflective
            Lafortune lobe), Lafortune's (cx, cy, cz) the axis of its lobe in general.
        width: the GGX width α of the draw (the lobe's own width: a microfacet m or α, Ward's α, or
            √(2/(n + 2)) for a cosine power n, whose cosⁿ falls like exp(−nθ²/2), a Beckmann lobe of that width).
        axis: A for ``"cone"`` (None for ``"half"``).
        lobe: the lobe it belongs to (for descriptions).
    """

    kind: str
    width: float
    axis: tuple | None = None
    lobe: str = ""


def power_width(n) -> float:
    """The width of a cosine power n as a `Peak` width: cosⁿθ ≈ exp(−nθ²/2) = exp(−θ²/m²) with m² = 2/n; (n + 2)
    keeps it finite for n → 0."""
    return math.sqrt(2.0 / (float(n) + 2.0))


def scalar(params: dict, name: str) -> float:
    """A parameter's value as one number (a colour parameter's mean over its channels)."""
    return float(np.mean(np.asarray(params[name], dtype=float)))
