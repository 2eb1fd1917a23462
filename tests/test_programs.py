"""Compiled programs kept across processes (`brdffit.programs`): a new process loads what an earlier one
compiled without tracing it, and a program whose key differs, whose file is damaged or that runs on tracers is
compiled (or traced) as plain ``jax.jit`` would."""

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdffit  # noqa: F401  (float64)
from brdffit import programs
from brdffit.programs import Program

TRACES = []


def polynomial():
    """A new function object each call (JAX keeps the traces of one function object in memory; a new process
    has none), which records each time JAX traces it."""
    def f(x, data):
        TRACES.append(np.shape(x))
        return jnp.sin(x) * data["a"] + data["b"] ** 2
    return f


def arguments(n: int):
    x = jnp.linspace(0.0, 1.0, n)
    return x, {"a": 2.0 * jnp.ones(n), "b": jnp.arange(n, dtype=float)}


@pytest.fixture
def kept_in(tmp_path):
    """JAX's persistent cache directory set to a fresh folder for the test, restored afterwards."""
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    TRACES.clear()
    yield tmp_path / "brdffit-programs"
    jax.config.update("jax_compilation_cache_dir", before)


def test_a_kept_program_runs_in_a_new_process_without_being_traced_and_a_damaged_one_is_replaced(tmp_path):
    script = f"""
import json, sys
import jax, jax.numpy as jnp, numpy as np
import brdffit
from brdffit.programs import Program
jax.config.update("jax_compilation_cache_dir", {str(tmp_path)!r})
traced = []
def f(model, x, data):
    traced.append(1)
    return jnp.cos(x) * data["a"] + jnp.sum(data["b"]) + model.params["rho_d"][0]
program = Program(f, "test program")
x = jnp.linspace(0.0, 1.0, 9)
# A Model among the arguments: a pytree with custom nodes (a registered dataclass), whose pickled tree does not
# unflatten in another process; the kept executable takes the arguments' leaves.
model = brdffit.models.get("lambert", rho_d=0.0)
out = program(model, x, {{"a": 3.0 * jnp.ones(9), "b": jnp.arange(9.0)}})
print(json.dumps({{"traced": len(traced), "out": np.asarray(out).tolist()}}))
"""

    def run():
        done = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True)
        return json.loads(done.stdout.strip().splitlines()[-1])

    x = np.linspace(0.0, 1.0, 9)
    first, second = run(), run()
    assert first["traced"] == 1 and second["traced"] == 0, (first, second)
    np.testing.assert_allclose(second["out"], np.cos(x) * 3.0 + 36.0, rtol=1e-15)
    assert second["out"] == first["out"]
    (path,) = (tmp_path / "brdffit-programs").glob("*.bin")
    path.write_bytes(b"not a program")
    damaged, replaced = run(), run()  # compiled again and the file replaced; then loaded
    assert damaged["traced"] == 1 and replaced["traced"] == 0, (damaged, replaced)
    assert damaged["out"] == replaced["out"] == first["out"]
    assert [p.name for p in (tmp_path / "brdffit-programs").iterdir()] == [path.name]  # no temporary file left


def test_each_signature_is_compiled_once_and_kept(kept_in):
    program = Program(polynomial(), "polynomial")
    for n in (5, 7, 5, 7):
        x, data = arguments(n)
        np.testing.assert_allclose(program(x, data), np.sin(x) * 2.0 + np.arange(n) ** 2, rtol=1e-15)
    assert TRACES == [(5,), (7,)]
    assert len(list(kept_in.glob("*.bin"))) == 2
    TRACES.clear()
    again = Program(polynomial(), "polynomial")  # a new Program (as in a new process) loads both without tracing
    for n in (5, 7):
        x, data = arguments(n)
        np.testing.assert_allclose(again(x, data), np.sin(x) * 2.0 + np.arange(n) ** 2, rtol=1e-15)
    assert TRACES == []
    # Another name is another program, even for the same function and shapes. (XLA's second compilation of the
    # same module in one process does not serialise into a copy that runs, so that one is kept in memory only:
    # `_keep` checks the copy.)
    x, data = arguments(5)
    np.testing.assert_allclose(Program(polynomial(), "another")(x, data), np.sin(x) * 2.0 + np.arange(5) ** 2)
    assert TRACES == [(5,)]


def test_numpy_and_device_arguments_share_an_executable_and_dtype_or_weak_type_keys_another(kept_in):
    # The in-memory key (`programs._kinds`): shape, canonical dtype and weak type, whatever holds the array.
    program = Program(polynomial(), "polynomial")
    x, data = arguments(5)
    expected = np.sin(np.asarray(x)) * 2.0 + np.arange(5) ** 2
    host = (np.asarray(x), {k: np.asarray(v) for k, v in data.items()})
    for args in (host, (x, data), host):
        out = program(*args)
        assert out.dtype == np.float64
        np.testing.assert_allclose(out, expected, rtol=1e-15)
    assert TRACES == [(5,)]
    single = program(host[0].astype(np.float32), {k: v.astype(np.float32) for k, v in host[1].items()})
    assert single.dtype == np.float32 and TRACES == [(5,), (5,)]
    np.testing.assert_allclose(single, expected, rtol=1e-6)
    weak = program(0.5, {"a": 2.0, "b": 3.0})  # Python numbers: weakly typed scalars
    assert TRACES == [(5,), (5,), ()]
    np.testing.assert_allclose(weak, np.sin(0.5) * 2.0 + 9.0, rtol=1e-15)
    program(np.float64(0.5), {"a": np.asarray(2.0), "b": np.asarray(3.0)})  # the same shapes, strongly typed
    assert TRACES == [(5,), (5,), (), ()]


def test_a_damaged_file_is_compiled_again(kept_in):
    Program(polynomial(), "polynomial")(*arguments(6))
    (path,) = kept_in.glob("*.bin")
    path.write_bytes(b"not a program")
    TRACES.clear()
    x, data = arguments(6)
    np.testing.assert_allclose(Program(polynomial(), "polynomial")(x, data), np.sin(x) * 2.0 + np.arange(6) ** 2)
    assert TRACES == [(6,)]


def test_without_a_cache_directory_nothing_is_written(tmp_path):
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", None)
    try:
        assert programs.program_directory() is None
        x, data = arguments(4)
        np.testing.assert_allclose(Program(polynomial(), "polynomial")(x, data), np.sin(x) * 2.0 + np.arange(4) ** 2)
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_on_tracers_a_program_is_part_of_the_outer_function(kept_in):
    program = Program(polynomial(), "polynomial")
    x, data = arguments(5)
    gradient = jax.grad(lambda x: jnp.sum(program(x, data)))(x)  # traced: differentiable like jax.jit
    np.testing.assert_allclose(gradient, np.cos(x) * 2.0, rtol=1e-15)
    assert not kept_in.exists()  # nothing compiled on its own


def test_static_arguments_key_the_program_and_addresses_are_not_kept(kept_in):
    def scaled(k, x):
        return x * (k if isinstance(k, float) else 1.0)

    program = Program(scaled, "scaled", static_argnums=(0,))
    np.testing.assert_allclose(program(2.0, jnp.ones(3)), 2.0)
    np.testing.assert_allclose(program(3.0, jnp.ones(3)), 3.0)
    assert len(list(kept_in.glob("*.bin"))) == 2
    np.testing.assert_allclose(program(object(), jnp.ones(3)), 1.0)  # repr names an address: memory only
    assert len(list(kept_in.glob("*.bin"))) == 2


def test_the_source_stamp_reads_the_package_only():
    """The key's source stamp digests brdffit's own files: every module of the package, and nothing of the folder
    it is installed in (a checkout's virtual environment, or site-packages, would be thousands of files)."""
    package = Path(programs.__file__).resolve().parent
    files = programs._source_files()
    assert all(package in path.parents for path in files)
    assert package / "programs.py" in files and package / "fitting" / "api.py" in files
    assert len(files) == len(list(package.rglob("*.py")))


def test_programs_compile_with_the_declared_options_and_the_options_key_the_kept_files(kept_in, monkeypatch):
    """On the CPU every program is compiled with `compiler_options` (XLA's loop emitters), a program compiled with
    other options is never loaded in their place (the options are part of the key), and the option leaves a
    program's values unchanged."""
    assert jax.default_backend() == "cpu"
    assert programs.compiler_options() == {"xla_cpu_use_fusion_emitters": False}
    seen = []
    compile_lowered = jax.stages.Lowered.compile

    def recording(self, compiler_options=None):
        seen.append(compiler_options)
        return compile_lowered(self, compiler_options=compiler_options)

    monkeypatch.setattr(jax.stages.Lowered, "compile", recording)
    x, data = arguments(40)
    emitted = np.asarray(Program(polynomial(), name="poly")(x, data))
    assert seen == [{"xla_cpu_use_fusion_emitters": False}]
    stamp = programs._stamp()
    monkeypatch.setattr(programs, "_CPU_OPTIONS", {"xla_cpu_use_fusion_emitters": True})
    assert programs._stamp() != stamp
    fused = np.asarray(Program(polynomial(), name="poly")(x, data))
    assert seen[-1] == {"xla_cpu_use_fusion_emitters": True}  # compiled anew, not loaded
    assert len(list(kept_in.glob("*.bin"))) == 2
    np.testing.assert_allclose(emitted, fused, rtol=1e-14, atol=0.0)


def _reset_prefetch(monkeypatch):
    """The prefetch state of a new process (the module's own dicts and sets replaced for the test)."""
    for name, value in (("_USED", {}), ("_QUEUED", set()), ("_TAKEN", {}), ("_FETCHED", {})):
        monkeypatch.setattr(programs, name, value)


def test_a_recorded_job_is_read_back_by_the_prefetch_and_used_without_tracing(kept_in, monkeypatch):
    """`record` writes the files a job used; a later process's `prefetch` of that job reads them in its thread, and
    a program takes its executable from there (the same values, no trace, no read of its own)."""
    _reset_prefetch(monkeypatch)
    for n in (23, 29):  # sizes no other test compiles (a second compilation in a process is not kept)
        Program(polynomial(), "polynomial")(*arguments(n))
    programs.record("a job")
    (manifest,) = (kept_in / "manifests").glob("*.txt")
    assert sorted(manifest.read_text().split()) == sorted(p.name for p in kept_in.glob("*.bin"))
    _reset_prefetch(monkeypatch)
    TRACES.clear()
    programs.prefetch("a job")
    reads = []
    monkeypatch.setattr(programs, "_read", lambda path, _read=programs._read: reads.append(path.name) or _read(path))
    again = Program(polynomial(), "polynomial")
    for n in (23, 29):
        x, data = arguments(n)
        np.testing.assert_allclose(again(x, data), np.sin(x) * 2.0 + np.arange(n) ** 2, rtol=1e-15)
    assert TRACES == []
    assert set(programs._TAKEN) | set(reads) == {p.name for p in kept_in.glob("*.bin")}
    assert not programs._QUEUED and not programs._FETCHED  # every file read once, by the thread or its caller


def test_a_manifest_that_no_longer_fits_costs_nothing_but_its_reads(kept_in, monkeypatch):
    """A manifest naming a missing file and a file of another key (damaged): the prefetch reads what it can, the
    programs run as without it (compiled again where nothing fits), and another job's manifest is not read."""
    _reset_prefetch(monkeypatch)
    Program(polynomial(), "polynomial")(*arguments(31))
    (path,) = kept_in.glob("*.bin")
    programs._USED["missing.bin"] = None
    programs.record("stale")
    path.write_bytes(b"not a program")
    _reset_prefetch(monkeypatch)
    TRACES.clear()
    programs.prefetch("another job")  # no manifest: nothing to read
    assert not programs._QUEUED and not programs._TAKEN
    programs.prefetch("stale")
    x, data = arguments(31)
    np.testing.assert_allclose(Program(polynomial(), "polynomial")(x, data), np.sin(x) * 2.0 + np.arange(31) ** 2)
    assert TRACES == [(31,)]
