"""Keys' cubic convolution on uniform axes: tables of smooth functions read between their nodes.

Keys, Cubic convolution interpolation for digital image processing, IEEE TASSP 29(6), 1981, Eq. 15 with a = −1/2
(Catmull-Rom): a C¹ interpolant exact for quadratics, from the four nodes around a point. Near an end of the
axis the missing neighbours are the end node repeated. Used by the lobes that read quantities of their interface
from tables (`brdffit.models.roughplastic`, `brdffit.models.coateddiffuse`); the ``xp`` argument is the array
module (``numpy`` or ``jax.numpy``).
"""

from __future__ import annotations

__all__ = ["weights", "cell", "read"]


def weights(t):
    """The weights of the four nodes around a point at fraction ``t`` of its cell (Keys 1981, Eq. 15)."""
    t2, t3 = t * t, t * t * t
    return (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)


def cell(nodes, x, xp):
    """(index of the node starting x's cell, fraction of the cell) of x on the uniform axis ``nodes``, x clamped
    to the axis."""
    step = (nodes[-1] - nodes[0]) / (len(nodes) - 1)
    c = xp.clip((x - nodes[0]) / step, 0.0, len(nodes) - 1.0)
    i = xp.minimum(xp.floor(c), len(nodes) - 2)
    return i.astype("int32"), c - i


def read(values, nodes, x, xp):
    """A 1-d table ``values`` at the uniform ``nodes``, read at ``x`` (any shape)."""
    i, t = cell(nodes, x, xp)
    out = 0.0
    for k, w in zip((-1, 0, 1, 2), weights(t)):
        out = out + w * values[xp.clip(i + k, 0, len(nodes) - 1)]
    return out
