"""Host values onto the device without compiling anything, and host columns through compiled functions.

``jnp.asarray`` of a NumPy array or a Python number runs a small compiled program (``jit(stage)``, or
``jit(convert_element_type)`` when it changes the dtype), and ``jnp.stack``, ``jnp.full`` and the like one each:
one compilation per shape and dtype in a new process (lowering included), and still a lowering and a cache
lookup each in a warm one. A first fit made dozens of them, a sizeable share of its time in a new process or a warm
one (docs/benchmarks.md). So the fitting pipeline builds its data's arrays (their fields, subsamples, stacks and
pieces) and its other small arrays in NumPy on the host, and only the model's own maths is compiled
(`brdffit.programs.Program`): a compiled program of the data's few operations would add its compilation to every
first fit. It hands those arrays to the compiled programs as they are, each call moving its arguments in JAX's C++
dispatch, or, where many calls read the same large arrays, moves them once with `on_device` (``jax.device_put``,
which compiles nothing but dispatches in Python; `for_calls`). Host-side maths on columns of samples in JAX
functions (the readers' and the report's angle conversions, the synthesised data) goes through `padded_columns`: a
jitted function called on lengths padded to a power of two, so that files of any length share a few compilations.
"""

from __future__ import annotations

import functools

import numpy as np

from ._lazy import module

jax = module("jax")  # loaded on first use: the readers import this module, and `brdffit info` loads no JAX

__all__ = ["to_device", "on_device", "on_host", "host_arrays", "for_calls", "traced", "jitted", "padded_columns",
           "COLUMN_CHUNK", "RECOPY_BYTES"]

# The most samples of one call of `padded_columns` (bounds the memory of a MERL-size table's intermediates).
COLUMN_CHUNK = 1 << 18

# `for_calls`: the bytes that, copied again by the later calls of compiled programs, cost about what one
# ``jax.device_put`` costs beyond its own copy. On the 2-core CPU host a ``device_put`` of a few arrays took 0.3-0.45 ms
# (its dispatch runs in Python), and a call copied NumPy arguments at about 5 GB/s, 0.2 ms a MB (docs/fitting.md).
RECOPY_BYTES = 2 << 20


def to_device(value, dtype=None):
    """``value`` as a JAX array, as ``jnp.asarray(value, dtype)`` gives it, without a compiled program.

    Arguments:
        value: a NumPy array, a number, a nested list, or a JAX array (returned as it is when its dtype is the one
            asked for; a tracer is converted by ``jnp.asarray``).
        dtype: the NumPy dtype wanted (``float``: JAX's default float, float64 in float64 mode, else float32), or
            None for the value's own, canonicalised the same way.

    Returns:
        A JAX array on the default device.
    """
    if isinstance(value, jax.Array):
        if dtype is None or value.dtype == jax.dtypes.canonicalize_dtype(dtype):
            return value
        if traced(value):
            import jax.numpy as jnp

            return jnp.asarray(value, dtype=dtype)
    return jax.device_put(host_arrays(np.asarray(value, dtype=dtype)))


def host_arrays(tree):
    """Every leaf of ``tree`` as a NumPy array of the dtype `to_device` would give it on the device (float64 ->
    float32 without float64 mode): the fitting pipeline's data, which it stacks and cuts on the host and hands to
    compiled programs as they are (`for_calls`)."""
    def host(leaf):
        array = np.asarray(leaf)
        return array.astype(jax.dtypes.canonicalize_dtype(array.dtype), copy=False)

    return jax.tree_util.tree_map(host, tree)


def on_device(tree):
    """Every leaf of ``tree`` (a NamedTuple, a dict, ...) as `to_device` gives it, the host leaves moved by one
    ``jax.device_put`` (a call per leaf costs a dispatch each, and a `fit_many` pass moves dozens).

    Arguments:
        tree: a pytree of NumPy arrays, numbers or JAX arrays.

    Returns:
        The same tree of JAX arrays on the default device (a dict in its own order of keys, not JAX's sorted one).
    """
    leaves, structure = jax.tree_util.tree_flatten(tree)
    host = [i for i, leaf in enumerate(leaves) if not isinstance(leaf, jax.Array)]
    out = [to_device(leaf) if isinstance(leaf, jax.Array) else leaf for leaf in leaves]
    if host:
        for i, moved in zip(host, jax.device_put([host_arrays(leaves[i]) for i in host])):
            out[i] = moved
    moved = structure.unflatten(out)
    return {key: moved[key] for key in tree} if type(tree) is dict else moved


def for_calls(tree, calls: int):
    """``tree``'s leaves as the ``calls`` calls of compiled programs that read them take them most cheaply: NumPy
    arrays (`host_arrays`), which each call copies to the device itself, in JAX's C++ dispatch (microseconds an
    array), or device arrays (`on_device`) where those copies would cost more than one ``jax.device_put``: more than
    `RECOPY_BYTES` copied again by the calls after the first.

    Arguments:
        tree: a pytree of NumPy arrays, numbers or JAX arrays.
        calls: how many program calls will read every leaf.

    Returns:
        The same tree, of NumPy arrays or of JAX arrays.
    """
    host = host_arrays(tree)
    size = sum(np.asarray(leaf).nbytes for leaf in jax.tree_util.tree_leaves(host))
    return on_device(host) if (calls - 1) * size > RECOPY_BYTES else host


def on_host(tree):
    """Every leaf of ``tree`` as a NumPy array (a view of a CPU device array; a copy from an accelerator)."""
    return jax.tree_util.tree_map(np.asarray, tree)


def traced(tree) -> bool:
    """True when a leaf of ``tree`` (an array, a `Model`, any pytree) is a JAX tracer: the value is being traced
    inside ``jax.jit``, ``jax.grad`` or the like, and cannot go through the host."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


@functools.lru_cache(maxsize=None)
def jitted(fn):
    """``jax.jit(fn)`` with brdffit's compiler options (`brdffit.programs.compiler_options`), made once per function
    so that its compilations are reused across calls."""
    from .programs import compiler_options  # here: brdffit.programs loads JAX, which `brdffit info` does not

    return jax.jit(fn, compiler_options=compiler_options())


def padded_columns(fn, *columns, chunk: int = COLUMN_CHUNK, least: int = 256) -> tuple:
    """``fn(*columns)`` on columns of one length (along their first axis), called on lengths padded with zeros to a
    power of two (at least ``least``) and in pieces of at most ``chunk`` samples, so that a compiled ``fn`` serves
    every length with a few compilations (called per length, or eagerly, it compiled anew for each file: seconds
    each); with ``least`` equal to ``chunk``, with one.

    Arguments:
        fn: a compiled (jitted) function of the columns, returning an array or a tuple of arrays of their length.
        columns: arrays of one length along their first axis (1-d, or rows such as ``(N, 3)`` vectors), converted to
            float64.
        chunk: the most samples of one call (a power of two).
        least: the fewest samples of one call (a power of two, at most ``chunk``).

    Returns:
        The outputs as float64 NumPy arrays cut back to the columns' length, a tuple.
    """
    columns = [np.asarray(c, dtype=float) for c in columns]
    n = columns[0].shape[0]
    pieces = []
    for start in range(0, max(n, 1), chunk):
        part = [c[start:start + chunk] for c in columns]
        size = part[0].shape[0]
        padded = max(least, 1 << max(size - 1, 0).bit_length())
        out = fn(*(np.pad(c, [(0, padded - size)] + [(0, 0)] * (c.ndim - 1)) for c in part))
        pieces.append([np.asarray(o, dtype=np.float64)[:size] for o in (out if isinstance(out, tuple) else (out,))])
    return tuple(np.concatenate(column, axis=0) for column in zip(*pieces))
