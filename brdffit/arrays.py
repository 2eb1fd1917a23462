"""Host values onto the device without compiling anything (issue 15).

``jnp.asarray`` of a NumPy array or a Python number runs a small compiled program (``jit(stage)``, or
``jit(convert_element_type)`` when it changes the dtype), and ``jnp.stack``, ``jnp.full`` and the like one each:
one compilation per shape and dtype, 10–40 ms each in a new process (lowering included), and still a lowering and
a cache lookup each in a warm one. A first fit made about thirty of them: 0.5–0.9 s of a 5–7 s single fit, 0.45 s
of a warm one (docs/benchmarks.md). ``jax.device_put`` of a NumPy array compiles nothing, so the fitting pipeline
builds small host-side arrays in NumPy and moves them with `to_device`; work on device arrays stays in compiled
programs (`brdffit.fitting.programs.Program`).
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["to_device"]


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
        if isinstance(value, jax.core.Tracer):
            import jax.numpy as jnp

            return jnp.asarray(value, dtype=dtype)
    array = np.asarray(value, dtype=dtype)
    return jax.device_put(array.astype(jax.dtypes.canonicalize_dtype(array.dtype), copy=False))
