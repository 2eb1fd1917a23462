"""Host values onto the device (`brdffit.arrays.to_device`), and a fit that runs no eager JAX operation: every
program a fit compiles is one of brdffit's own (issue 15: each eager operation compiled a program of its own)."""

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdffit  # noqa: F401  (float64)
from brdffit.arrays import RECOPY_BYTES, for_calls, jitted, on_device, padded_columns, to_device


@pytest.mark.parametrize("value, dtype", [(np.arange(5.0), None), (np.arange(4), None), (np.arange(4), float),
                                          (0.5, None), (3, float), ([[1.0, 2.0]], None), (np.array([True]), None),
                                          (np.int32(7), None)])
def test_to_device_gives_what_jnp_asarray_gives(value, dtype):
    got, want = to_device(value, dtype), jnp.asarray(value, dtype=dtype)
    assert isinstance(got, jax.Array) and got.dtype == want.dtype and got.shape == want.shape
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_to_device_keeps_a_device_array_and_converts_one_of_another_dtype():
    a = jnp.arange(3.0)
    assert to_device(a) is a and to_device(a, float) is a
    converted = to_device(jnp.arange(3), float)
    assert converted.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(converted), [0.0, 1.0, 2.0])


def test_to_device_inside_a_traced_function_stays_traced():
    gradient = jax.grad(lambda x: jnp.sum(to_device(x, float) ** 2))(jnp.arange(3.0))
    np.testing.assert_array_equal(np.asarray(gradient), [0.0, 2.0, 4.0])


def test_to_device_in_float32_mode_gives_float32():
    with jax.enable_x64(False):
        assert to_device(np.arange(3.0)).dtype == jnp.float32 == jnp.asarray(np.arange(3.0)).dtype


def test_a_fit_in_a_new_process_compiles_only_brdffit_programs(tmp_path):
    # A new process (JAX's in-memory caches empty), no persistent cache, the data read from a file (nothing of JAX
    # ran before the fit): every compilation is logged. An eager jax.numpy or lax operation compiles under its own
    # name (jnp.asarray of a NumPy array as "stage").
    path = tmp_path / "ggx.csv"
    brdffit.io.save(brdffit.synth.generate("lambert+ggx", n=1500, noise="relative:0.01", seed=3), path)
    script = f"""
import json, logging
import jax, jax.numpy as jnp
names = []
class Names(logging.Handler):
    def emit(self, record):
        message = record.getMessage()
        if message.startswith("Finished XLA compilation of jit("):
            names.append(message.split("jit(", 1)[1].split(")", 1)[0])
handler = Names(level=logging.DEBUG)
for logger in ("jax._src.dispatch", "jax._src.interpreters.pxla", "jax._src.compiler"):
    logging.getLogger(logger).addHandler(handler)
    logging.getLogger(logger).setLevel(logging.DEBUG)
jax.config.update("jax_log_compiles", True)
import brdffit
result = brdffit.fit(brdffit.io.load({str(path)!r}), "lambert+ggx")
eager = set(dir(jnp)) | set(dir(jax.lax)) | {{"stage", "_where", "_reduce_sum", "_reduce_max", "_reduce_min"}}
print(json.dumps({{"status": result.status, "names": sorted(set(names)), "eager": sorted(set(names) & eager)}}))
"""
    env = {"PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu", "HOME": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["status"] == "converged"
    # The model's two programs and nothing else: the search's amplitude sums ("one") and the pass
    # ("point_tangents", the tangents and residuals that every solver step, the covariance and the metrics use, on
    # its slots). The data's own arrays are prepared in NumPy (`brdffit.fitting.problem`), so no program of theirs
    # compiles.
    assert report["names"] == ["one", "point_tangents"]
    assert report["eager"] == []


TRACED = []


def _angles(theta, phi):
    TRACED.append(theta.shape)
    return jnp.sin(theta) * jnp.cos(phi), theta + phi


@pytest.mark.parametrize("n, chunk", [(1, 1 << 18), (300, 1 << 18), (700, 256), (0, 1 << 18)])
def test_padded_columns_gives_the_function_on_the_columns(n, chunk, rng):
    theta, phi = rng.uniform(0.0, 1.5, n), rng.uniform(0.0, 6.0, n)
    a, b = padded_columns(jitted(_angles), theta, phi, chunk=chunk)
    assert a.dtype == np.float64 and a.shape == b.shape == (n,)
    np.testing.assert_allclose(a, np.sin(theta) * np.cos(phi), rtol=1e-15)
    np.testing.assert_allclose(b, theta + phi, rtol=1e-15)


def test_padded_columns_compiles_once_for_lengths_within_a_power_of_two(rng):
    fn = jitted(lambda theta, phi: _angles(theta, phi)[0])  # a function of its own: a fresh trace count
    TRACED.clear()
    for n in (520, 700, 1024):
        (out,) = padded_columns(fn, np.ones(n), np.zeros(n))
        np.testing.assert_allclose(out, np.sin(1.0))
    assert TRACED == [(1024,)]


def test_on_device_moves_a_dict_and_keeps_its_order_of_keys():
    moved = on_device({"rho_d": np.ones(3), "ks": 0.5, "alpha": jnp.asarray(0.1)})
    assert list(moved) == ["rho_d", "ks", "alpha"]
    assert all(isinstance(v, jax.Array) for v in moved.values())
    np.testing.assert_array_equal(moved["rho_d"], np.ones(3))


def test_for_calls_moves_arrays_once_only_where_the_later_calls_would_copy_more_than_recopy_bytes():
    # (calls − 1) × bytes against RECOPY_BYTES: a piece that one call reads, or a few calls of a small piece,
    # stay NumPy (each call copies them in JAX's C++ dispatch); a large piece read by several calls is moved once.
    small = {"values": np.ones((1, 4096, 3)), "mask": np.ones((1, 4096, 3), bool)}  # 110,592 bytes
    large = {"values": np.ones((1, RECOPY_BYTES // 8, 1)), "mask": np.ones((1, 8, 1), bool)}  # just over
    for tree, calls, moved in [(small, 1, False), (small, 19, False), (small, 20, True), (large, 1, False),
                               (large, 2, True)]:
        out = for_calls(tree, calls)
        assert all(isinstance(v, jax.Array) == moved for v in out.values()), (calls, moved)
        assert all(isinstance(v, np.ndarray) != moved for v in out.values())
        np.testing.assert_array_equal(out["values"], tree["values"])
        assert out["mask"].dtype == np.bool_
