"""Multilinear reading of a table sampled on a regular grid over [0, 1] in each of its axes: the albedo tables of
the renderers' models (`brdffit.models.gltf.sheen_albedo`, Cycles' tables in `brdffit.models.blender`), read as
the renderers read theirs (Cycles' ``lookup_table_read_2D``/``_3D``: nodes at i/(n − 1), arguments clamped)."""

from __future__ import annotations

import itertools

from .._lazy import module

jnp = module("jax.numpy")

__all__ = ["multilinear"]


def multilinear(table, *coords):
    """The table's value at ``coords`` by multilinear interpolation between the 2^d surrounding nodes.

    Arguments:
        table: an array of d axes, each of at least 2 nodes at i/(n − 1).
        coords: d coordinates in [0, 1] (clamped), the k-th indexing the table's k-th axis; any broadcastable
            shapes.

    Returns:
        The interpolated values, the coordinates' broadcast shape.
    """
    table = jnp.asarray(table)
    split = []
    for n, c in zip(table.shape, coords):
        c = jnp.clip(c, 0.0, 1.0) * (n - 1)
        i = jnp.minimum(jnp.floor(c), n - 2).astype(jnp.int32)
        split.append((i, c - i))
    value = 0.0
    for corner in itertools.product((0, 1), repeat=len(coords)):
        weight, index = 1.0, []
        for (i, t), upper in zip(split, corner):
            weight = weight * (t if upper else 1.0 - t)
            index.append(i + upper)
        value = value + weight * table[tuple(index)]
    return value
