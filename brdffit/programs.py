"""Compiled programs kept across processes, without tracing them again.

JAX's persistent compilation cache (which the CLI turns on, `brdffit.compilation_cache.enable_compilation_cache`) saves XLA's
compilation in a new process, not the tracing and the lowering to StableHLO that it needs to compute its key: in a
warm `brdffit fit FILE` those would be most of the time left (tracing and lowering the programs of a selection's
candidates takes longer than fitting them). A `Program` is a jitted function that also keeps each
executable it compiles on disk, under a key that it can compute *before* tracing: the program's name, the values
of its static arguments, the tree structure and the shapes and dtypes of its array arguments, and a stamp of
everything that could change the program (brdffit's source files, the JAX and jaxlib versions, the backend and its
device, float64 mode, ``XLA_FLAGS``). A later process with the same key loads the executable
(`jax.experimental.serialize_executable`, far cheaper than tracing) and runs it.

Persistence is on exactly when JAX's persistent cache directory is configured: the executables go to its
``brdffit-programs`` folder. Otherwise, when called on tracers (inside another jitted function), or when a static
argument has no stable text (its repr names a memory address), a `Program` is plain ``jax.jit``. A file that cannot
be read back or does not run (damaged, or written by another version that happened to share the key) is compiled
again and replaced; files are written to a temporary name and renamed, so a reader never sees half of one.

A `Program` may be called from several threads (`brdffit.select` fits candidates concurrently): the first call of
a signature compiles it while later callers of that signature wait for it, and other signatures compile beside it.

Reading a kept executable back costs about 10 ms (a warm default fit of a real file reads some fifty), mostly
outside Python's lock. A process that knows its job (the CLI: the command, its options and the data's shape) names
it (`prefetch`): the executables that the last process with that job used (its manifest, `record`) are then read in
a background thread while this one imports and reads its data, and a program finds its own there. A manifest that
no longer fits (other data, an edited source) only costs that thread its reads: a program whose key differs, or
that the thread has not reached, is read by its caller as before.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import tempfile
import threading
from pathlib import Path

import jax
import numpy as np
from jax._src import config as _jax_config  # its options as thread-local context managers

__all__ = ["Program", "program_directory", "compiler_options", "prefetch", "record"]

_FOLDER = "brdffit-programs"
# XLA's options for brdffit's programs on the CPU: the loop emitters that preceded XLA's MLIR fusion emitters. They
# compile a selection's programs (passes, searches, residuals, a report's evaluations) in about 0.6 of the time,
# and the programs run as fast (docs/benchmarks.md); a default fit of a real file spends most of an empty-cache run
# compiling.
_CPU_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def compiler_options() -> dict | None:
    """The XLA compiler options of brdffit's programs on the default backend (`_CPU_OPTIONS` on the CPU, XLA's
    defaults, None, elsewhere), for ``jax.jit(..., compiler_options=...)`` or ``Lowered.compile``."""
    return dict(_CPU_OPTIONS) if jax.default_backend() == "cpu" else None


def program_directory() -> Path | None:
    """The folder of the kept executables: ``brdffit-programs`` in JAX's persistent cache directory, or None when
    no such directory is configured (nothing is kept)."""
    base = jax.config.jax_compilation_cache_dir
    return Path(base) / _FOLDER if base else None


def _source_files() -> list[Path]:
    """brdffit's Python source files: those of the package's own folder, not of the folder it is installed in (a
    site-packages or a checkout with its virtual environment holds thousands of other packages' files)."""
    return sorted(Path(__file__).resolve().parent.rglob("*.py"))


@functools.lru_cache(maxsize=1)
def _source_stamp() -> str:
    """A digest of brdffit's Python source files (`_source_files`): any edit gives every program a new key."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in _source_files():
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _stamp() -> str:
    """What besides the key's own parts decides a compiled program: the source, JAX, the device, float64 mode, XLA's
    flags and the compiler options."""
    import jaxlib

    device = jax.devices()[0]
    return "|".join([_source_stamp(), jax.__version__, jaxlib.__version__, device.platform,
                     getattr(device, "device_kind", ""), str(jax.config.jax_enable_x64),
                     os.environ.get("XLA_FLAGS", ""), repr(compiler_options())])


class Program:
    """A function compiled once per argument signature, in memory and, where JAX's persistent cache directory is
    configured, on disk (module doc).

    Arguments:
        fn: the function to compile (pure, JAX-traceable); its name and docstring become the program's, so that
            ``Program`` also serves as a decorator of a module-level function.
        name: the program's name in its keys; it must say everything ``fn`` captures from its closure (for example
            the problem structure a pass was built for). Default: ``fn``'s module and qualified name (enough for a
            module-level function, which captures nothing).
        static_argnums: positions of arguments that are compile-time constants (hashable, with a stable repr).
    """

    def __init__(self, fn, name: str | None = None, static_argnums: tuple = ()):
        functools.update_wrapper(self, fn)
        self._fn = fn
        self._jit = jax.jit(fn, static_argnums=static_argnums)
        self._name = name if name is not None else f"{fn.__module__}.{fn.__qualname__}"
        self._static = tuple(static_argnums)
        self._compiled: dict = {}
        self._locks: dict = {}

    def __call__(self, *args):
        static = tuple(args[i] for i in self._static)
        dynamic = tuple(a for i, a in enumerate(args) if i not in self._static)
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        kinds = _kinds(leaves)
        if kinds is None:
            return self._jit(*args)
        key = (static, tree, kinds)
        executable = self._compiled.get(key)
        if executable is not None:
            return executable(*leaves)
        with self._locks.setdefault(key, threading.Lock()):  # one thread compiles a signature
            executable = self._compiled.get(key)
            if executable is not None:
                return executable(*leaves)
            path, text = self._path((static, tree, tuple(jax.api_util.shaped_abstractify(leaf) for leaf in leaves)))
            if path is not None:
                _used(path)
            executable = _load(path, text) if path is not None else None
            out = _run(executable, leaves)
            if out is None:  # nothing kept, or a kept file that does not run: compile (and keep)
                executable, out = self._compile(static, tree, leaves, path, text)
            self._compiled[key] = executable
        return out

    def _of_leaves(self, static: tuple, tree):
        """The function of a signature's array leaves, jitted: its executables take only the leaves, so that a kept
        one unpickles in another process whatever the arguments' tree (a pickled tree with custom nodes, such as a
        `Model`'s, does not unflatten there)."""
        def fn(*leaves):
            dynamic = tree.unflatten(leaves)
            pending, fixed = iter(dynamic), iter(static)
            return self._fn(*(next(fixed) if i in self._static else next(pending)
                              for i in range(len(static) + len(dynamic))))

        fn.__name__, fn.__qualname__ = self._fn.__name__, self._fn.__qualname__  # JAX's logs and profiles name it
        return jax.jit(fn)

    def _path(self, signature):
        """The file and the full key text of a signature, or ``(None, None)`` where nothing is kept."""
        directory = program_directory()
        statics = repr(signature[0])
        if directory is None or " at 0x" in statics:
            return None, None
        text = "\n".join([_stamp(), self._name, statics, str(signature[1]), str(signature[2])])
        return directory / (hashlib.sha256(text.encode()).hexdigest() + ".bin"), text

    def _compile(self, static: tuple, tree, leaves: list, path, text):
        """Compile for a new signature and, with a ``path``, keep the executable there if a copy read back from
        its serialised form runs on these arguments. XLA compiles it itself, not JAX's persistent cache: on the
        CPU an executable that JAX's cache loaded (or the second compilation of a module in one process)
        serialises without its compiled functions, and a copy read back fails when it runs ("Function ... not
        found"); the check keeps such a copy from ever being written.

        Returns:
            ``(executable, output on the leaves)``: the output is the checked copy's where it ran (the program runs
            once either way).
        """
        program = self._of_leaves(static, tree)
        if path is None:
            compiled = program.lower(*leaves).compile(compiler_options=compiler_options())
            return compiled, compiled(*leaves)
        with _jax_config.enable_compilation_cache(False):  # in this thread only
            compiled = program.lower(*leaves).compile(compiler_options=compiler_options())
        out = _keep(path, text, compiled, leaves)
        return compiled, (compiled(*leaves) if out is None else out)


def _kinds(leaves) -> tuple | None:
    """What of each array argument decides the executable in this process: its shape, its dtype as JAX takes it
    (canonical: float64 is float32 without float64 mode) and whether its type is weak; None where a leaf is a tracer
    (the call is being traced). Cheaper than ``jax.api_util.shaped_abstractify``, which took 9 µs for a NumPy array
    (a pass has some twenty), and used as the in-memory key only: the file's key text is formed from the abstract
    values, once per signature."""
    kinds = []
    for leaf in leaves:
        if isinstance(leaf, np.ndarray):
            kinds.append((leaf.shape, jax.dtypes.canonicalize_dtype(leaf.dtype), False))
        elif isinstance(leaf, jax.core.Tracer):
            return None
        elif isinstance(leaf, jax.Array):
            kinds.append((leaf.shape, leaf.dtype, leaf.weak_type))
        else:  # a number or a NumPy scalar
            kinds.append(jax.api_util.shaped_abstractify(leaf))
    return tuple(kinds)


def _run(executable, leaves):
    """The output of a loaded executable on the arguments' ``leaves``, or None when there is none or it does not
    run."""
    if executable is None:
        return None
    try:
        return jax.block_until_ready(executable(*leaves))
    except Exception:  # noqa: BLE001 - compiled again by the caller, and the file replaced
        return None


def _load(path: Path, text: str):
    """The executable kept under ``path`` for the key ``text``, or None (absent, damaged, another key): the one
    `prefetch` read, where it read this file, else read here."""
    fetched = _prefetched(path.name)
    if fetched is not None and fetched[0] == text:
        return fetched[1]
    stored, executable = _read(path)
    return executable if stored == text else None


def _read(path: Path) -> tuple:
    """``(key text, executable)`` of a kept file, ``(None, None)`` where it cannot be read back."""
    try:
        with open(path, "rb") as f:
            stored, blob, in_tree, out_tree = pickle.load(f)
        from jax.experimental.serialize_executable import deserialize_and_load

        return stored, deserialize_and_load(blob, in_tree, out_tree)
    except Exception:  # noqa: BLE001 - any failure to read it back means: compile it again
        return None, None


# The kept files this process used, in order of first use (`record`), and `prefetch`'s state: the files its thread
# has still to read (a caller that needs one first reads it itself) and, for each file it took, an event set when
# its read is done and the result.
_LOCK = threading.Lock()
_USED: dict[str, None] = {}
_QUEUED: set = set()
_TAKEN: dict[str, threading.Event] = {}
_FETCHED: dict[str, tuple] = {}


def _used(path: Path) -> None:
    with _LOCK:
        _USED.setdefault(path.name, None)


def _manifest(job: str) -> Path | None:
    """The manifest file of a job, in the programs' folder (None where nothing is kept)."""
    directory = program_directory()
    return None if directory is None else directory / "manifests" / (hashlib.sha256(job.encode()).hexdigest() + ".txt")


def prefetch(job: str) -> None:
    """Read, in a daemon thread, the kept executables that the last process with this ``job`` used (module doc).

    Arguments:
        job: what this process is about to do, in words that decide its programs (the CLI: its command, options and
            the data's shape); `record` under the same words writes the manifest this reads.
    """
    manifest = _manifest(job)
    try:
        names = manifest.read_text().split() if manifest is not None else []
    except OSError:
        return
    folder = manifest.parent.parent
    with _LOCK:
        names = [n for n in names if n not in _TAKEN and n not in _QUEUED]
        _QUEUED.update(names)
    if names:
        threading.Thread(target=_read_all, args=(folder, names), name="brdffit prefetch", daemon=True).start()


def _read_all(folder: Path, names: list) -> None:
    for name in names:
        with _LOCK:
            if name not in _QUEUED:  # a caller came first
                continue
            _QUEUED.discard(name)
            done = _TAKEN[name] = threading.Event()
        try:
            _FETCHED[name] = _read(folder / name)
        finally:
            done.set()


def _prefetched(name: str) -> tuple | None:
    """The prefetch thread's ``(key text, executable)`` of a file (waiting while it reads it), or None where it has
    not taken it (the caller reads it: the thread then skips it)."""
    with _LOCK:
        if name in _QUEUED:
            _QUEUED.discard(name)
            return None
        done = _TAKEN.get(name)
    if done is None:
        return None
    done.wait()
    return _FETCHED.pop(name, None)


def record(job: str) -> None:
    """Write the kept files this process used as ``job``'s manifest, for the next process's `prefetch` (atomically;
    a folder that cannot be written only costs the next process its prefetch)."""
    from .io._common import atomic_path

    manifest = _manifest(job)
    with _LOCK:
        names = list(_USED)
    if manifest is None or not names:
        return
    try:
        manifest.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(manifest) as temporary:
            temporary.write_text("\n".join(names) + "\n")
    except OSError:
        pass


def _keep(path: Path, text: str, compiled, leaves):
    """Write a compiled program atomically, if the copy that a later process would read from the file runs on the
    arguments' ``leaves``: the check deserialises the executable with its trees as pickled, so a tree that does not
    survive pickling (custom nodes) is never written. A folder that cannot be written, or a backend that cannot
    serialise, only costs the next process its compilation.

    Returns:
        The read-back copy's output on ``leaves``, or None where it did not run (or nothing could be serialised).
    """
    from jax.experimental.serialize_executable import deserialize_and_load, serialize

    temporary, out = None, None
    try:
        payload = pickle.dumps((text, *serialize(compiled)), protocol=pickle.HIGHEST_PROTOCOL)
        _, blob, in_tree, out_tree = pickle.loads(payload)
        out = _run(deserialize_and_load(blob, in_tree, out_tree), leaves)
        if out is None:
            return None
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
        os.replace(temporary, path)
    except Exception:  # noqa: BLE001 - serialisation unsupported here, or the folder unwritable
        if temporary is not None:
            try:
                os.unlink(temporary)
            except OSError:
                pass
    return out
