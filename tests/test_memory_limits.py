"""Memory proportional to the input: a reader asks for memory of the file's size, never for the 2 GiB it
may read at most; every command of docs/cli.md runs under an address-space limit of 2 GiB (``ulimit -v 2097152``,
set with ``resource.setrlimit(RLIMIT_AS)`` in the child) on the shipped and the shared files; and a read that
reaches the limit exits 2 with one line that names the limit, never a traceback."""

import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from brdffit import _memory, cli
from brdffit.io import _common
from brdffit.io._common import FormatError, memory_limit, out_of_memory, read_file_bytes

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "data" / "synthetic"
DATA = ROOT.parent / "shared" / "data"
PTFE_OPTIONS = ["--columns", "theta_i=thetai,phi_i=phi,theta_o=thetar,phi_o=phir", "--values", "f_r11",
                "--where", "lambda=0.532"]
LIMIT = 2 << 30  # ulimit -v 2097152 (KiB)
# subprocess.Popen forks before exec; JAX (loaded by other tests of the worker) warns of any fork.
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")

needs_shared = pytest.mark.skipif(not DATA.is_dir(), reason=f"the shared real measurements are not at {DATA} "
                                                            "(../shared/data beside the project)")


def brdffit(args, limit=LIMIT, cwd=ROOT, timeout=300):
    """``python -m brdffit.cli ARGS`` in a child whose address space is limited to ``limit`` bytes."""
    def set_limit():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return subprocess.run([sys.executable, "-m", "brdffit.cli", *map(str, args)], cwd=cwd, preexec_fn=set_limit,
                          capture_output=True, text=True, timeout=timeout)


def assert_ok(run):
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr and "MemoryError" not in run.stderr, run.stderr[-3000:]


# ------------------------------------------------------------------------------------------- reading the bytes
def test_a_small_file_is_read_under_a_2_gib_limit(tmp_path):
    """The measured failure: a 4 KB table under ulimit -v 2 GiB was a MemoryError, read() asking for 2 GiB."""
    path = tmp_path / "small.csv"
    path.write_text("theta_i,phi_i,theta_o,phi_o,value\n" + "10,0,20,180,0.25\n" * 200)
    code = f"from brdffit.io._common import read_file_bytes; print(len(read_file_bytes({str(path)!r})))"

    def set_limit():
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))

    run = subprocess.run([sys.executable, "-c", code], preexec_fn=set_limit, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == str(path.stat().st_size), run.stderr


def test_the_read_asks_for_the_file_size_not_the_bound(tmp_path, monkeypatch):
    path = tmp_path / "t.csv"
    path.write_bytes(b"x" * 1000)
    asked = []
    real_open = _common.open_regular

    def recording_open(p):
        fh = real_open(p)
        read = fh.read

        class Recorder:
            def read(self, n=-1):
                asked.append(n)
                return read(n)

            def fileno(self):
                return fh.fileno()

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                fh.close()

        return Recorder()

    monkeypatch.setattr(_common, "open_regular", recording_open)
    assert read_file_bytes(path) == b"x" * 1000
    assert asked == [1001]  # the size and one byte more, to see whether it grew


def test_a_file_that_grew_after_its_size_was_taken_is_read_whole_up_to_the_bound(tmp_path, monkeypatch):
    path = tmp_path / "t.csv"
    path.write_bytes(bytes(range(256)) * 4)
    with open(path, "rb") as fh:
        assert _common._read_sized(fh, 10) == path.read_bytes()  # fstat said 10 bytes, the file holds 1024
    monkeypatch.setattr(_common, "MAX_FILE_BYTES", 100)
    monkeypatch.setattr(_common, "_GROWN_CHUNK", 7)
    with open(path, "rb") as fh:
        assert len(_common._read_sized(fh, 10)) == 101  # one byte past the bound: refused by the caller
    real_fstat = os.fstat
    monkeypatch.setattr(_common.os, "fstat", lambda fd: os.stat_result((*real_fstat(fd)[:6], 10, *real_fstat(fd)[7:])))
    with pytest.raises(FormatError, match="larger than the 100 bytes a reader takes"):
        read_file_bytes(path)


# ------------------------------------------------------------------------------------------- the limit's words
def test_the_message_names_the_limit(monkeypatch):
    import resource as res

    limits = {res.RLIMIT_AS: (2 << 30, res.RLIM_INFINITY), res.RLIMIT_DATA: (res.RLIM_INFINITY,) * 2}
    monkeypatch.setattr(res, "getrlimit", lambda which: limits.get(which, (res.RLIM_INFINITY,) * 2))
    assert memory_limit() == "the address-space limit (ulimit -v) of 2 GiB"
    limits[res.RLIMIT_DATA] = (512 << 20, 512 << 20)
    assert memory_limit() == "the data-segment limit (ulimit -d) of 512 MiB"  # the smaller one is reached first
    limits[res.RLIMIT_AS] = limits[res.RLIMIT_DATA] = (res.RLIM_INFINITY,) * 2
    assert memory_limit() == "the memory available to the process"
    assert out_of_memory("reading its 1,000 bytes").startswith("out of memory reading its 1,000 bytes: more memory "
                                                               "is needed than the memory available")


def test_a_memory_error_while_reading_is_a_format_error_naming_file_and_limit(tmp_path, monkeypatch):
    path = tmp_path / "t.csv"
    path.write_text("theta_i,phi_i,theta_o,phi_o,v\n10,0,20,180,0.2\n")

    def no_memory(fh, size):
        raise MemoryError

    monkeypatch.setattr(_common, "_read_sized", no_memory)
    with pytest.raises(FormatError, match=r"t\.csv: out of memory reading its 46 bytes: more memory is needed than "):
        read_file_bytes(path)


def test_malloc_arenas_are_capped_only_under_an_address_space_limit(monkeypatch):
    import resource as res

    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    monkeypatch.setattr(res, "getrlimit", lambda which: (res.RLIM_INFINITY,) * 2)
    assert _memory.cap_malloc_arenas() is False
    monkeypatch.setenv("MALLOC_ARENA_MAX", "8")
    monkeypatch.setattr(res, "getrlimit", lambda which: (LIMIT, LIMIT))
    assert _memory.cap_malloc_arenas() is False  # the user's own setting stands


# ---------------------------------------------------------------------------------- a limit reached: exit 2
@pytest.mark.parametrize("suffix", [".csv", ".alta", ".binary", ".bsdf"])
def test_a_read_that_reaches_the_limit_exits_2_naming_it(tmp_path, suffix):
    """A 1.5 GiB file (sparse: it takes no disk) under a 1 GiB limit: the read cannot get its memory."""
    path = tmp_path / f"huge{suffix}"
    with open(path, "wb") as fh:
        fh.truncate(3 << 29)
    run = brdffit(["info", path], limit=1 << 30, timeout=120)
    assert run.returncode == cli.EXIT_BAD_INPUT, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    assert f"{path}: out of memory reading its 1,610,612,736 bytes" in lines[0]
    assert "the address-space limit (ulimit -v) of 1 GiB" in lines[0]


def test_a_memory_error_anywhere_in_a_command_exits_2_naming_the_limit(monkeypatch, capsys):
    def exhausted(args):
        raise MemoryError

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    for action in parser._subparsers._group_actions[0].choices.values():
        action.set_defaults(run=exhausted)
    assert cli.main(["models"]) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("brdffit models: error: out of memory") and "Traceback" not in err
    assert memory_limit() in err


# ------------------------------------------------------------------------------ every command under 2 GiB
@pytest.mark.parametrize("path", sorted(SYNTHETIC.glob("*.h5")), ids=lambda p: p.stem)
def test_info_reads_every_shipped_file_under_2_gib(path):
    assert_ok(brdffit(["info", path]))


@needs_shared
@pytest.mark.parametrize("name", ["nist-ptfe/PTFE.data.csv", "alta-cea-retro/retro-gray-tape.dat",
                                  "rgl-epfl/paper_white_rgb.bsdf", "rgl-epfl/acrylic_felt_green_rgb.bsdf",
                                  "rgl-epfl/satin_rosaline_rgb.bsdf", "rgl-epfl/cg_sunflower_rgb.bsdf",
                                  "rgl-epfl/cc_ibiza_sunset_rgb.bsdf"])
def test_info_reads_every_shared_file_under_2_gib(name):
    options = PTFE_OPTIONS if name.endswith(".csv") else []
    assert_ok(brdffit(["info", DATA / name, *options]))


# Every command has a run as ``python -m brdffit.cli`` in a process of its own somewhere in the suite: fit and
# posterior in tests/test_locking.py and test_kill.py, info in the tests above, the others in `own_children` below,
# each in a child under the limit. The commands that have such a run elsewhere, and the second run of export and of
# convert, run here in one child under the limit, one after the other, through `brdffit.cli.main` (what
# ``python -m brdffit.cli`` calls); it exits at the first that does not return 0. Its address space holds each
# command on top of what the earlier ones left (JAX and its compiled programs among them), so a command that passes
# there runs under the limit alone too: 10 start-ups (Python, JAX, the compilation cache) instead of 16, and no
# weaker a bound. The child prints its peak after each command, so that a failure shows how close the others came.
_IN_ONE_CHILD = """
import re, sys
from brdffit.cli import main

for args in COMMANDS:
    code = main(args)
    peak = int(re.search(r"VmPeak:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) >> 10
    print(f"brdffit {' '.join(args)}: exit {code}, VmPeak {peak} MiB", file=sys.stderr, flush=True)
    if code:
        sys.exit(code)
"""


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="prints the peak address space from /proc (Linux)")
def test_every_command_runs_under_2_gib(tmp_path):
    """The commands of docs/cli.md, one after the other on the shipped clay (a plausible fit, which `export`
    writes) and what they write; how they are grouped into child processes is said above."""
    out = tmp_path / "clay.brdffit"
    h5 = out / "result.h5"
    in_one_child = [
        ["fit", SYNTHETIC / "clay.h5", "--model", "oren-nayar", "--out", out],
        ["posterior", h5, "--walkers", "16", "--steps", "40"],
        ["export", h5, "--to", "mitsuba", "--fit", "--out", tmp_path / "clay.xml"],
        ["export", h5, "--to", "pbrt", "--fit"],
        ["convert", h5, tmp_path / "clay.binary"],
        ["info", tmp_path / "clay.binary"],
        ["fit", SYNTHETIC / "plastic.h5", "--model", "lambert+ggx", "--no-report", "--out", tmp_path / "plastic"],
    ]
    own_children = [
        ["models"],
        ["--version"],
        ["export", h5, "--to", "json"],
        ["report", h5, "--out", tmp_path / "report"],
        ["render", h5, "--resolution", "48", "--out", tmp_path / "clay.png"],
        ["synth", "lambert+ggx", "--n", "400", "--out", tmp_path / "synth.csv"],
        ["convert", tmp_path / "synth.csv", tmp_path / "synth.h5"],
        ["select", SYNTHETIC / "clay.h5", "--candidates", "lambert;oren-nayar"],
        ["batch", str(SYNTHETIC / "*.h5"), "--model", "lambert", "--workers", "1", "--out", tmp_path / "batch.csv"],
    ]

    def set_limit():
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))

    code = _IN_ONE_CHILD.replace("COMMANDS", repr([[str(arg) for arg in args] for args in in_one_child]))
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, preexec_fn=set_limit, capture_output=True, text=True,
                         timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr and "MemoryError" not in run.stderr, run.stderr[-3000:]
    done = [line for line in run.stderr.splitlines() if line.startswith("brdffit ") and ": exit 0, VmPeak " in line]
    assert len(done) == len(in_one_child), run.stderr[-3000:]  # every command ran, and returned 0
    for args in own_children:
        run = brdffit(args)
        assert run.returncode == 0, (args, run.stderr[-3000:])
        assert "Traceback" not in run.stderr and "MemoryError" not in run.stderr, (args, run.stderr[-3000:])


@needs_shared
@pytest.mark.slow
def test_a_fit_of_a_shared_file_runs_under_2_gib(tmp_path):
    run = brdffit(["fit", DATA / "rgl-epfl" / "cg_sunflower_rgb.bsdf", "--model", "lambert+ggx", "--no-report",
                   "--out", tmp_path / "sunflower"])
    assert run.returncode in (cli.EXIT_OK, 1), run.stderr[-3000:]  # 1: converged or not, a result and no crash
    assert "Traceback" not in run.stderr


# ------------------------------------------------------------------------------------ memory of the readers
def _peak_increase(path) -> tuple[float, int]:
    """(peak resident memory that reading ``path`` added, in multiples of its size; samples read), in a child."""
    # The peak of this child's own memory (VmHWM): getrusage's ru_maxrss is kept across exec, so a child of a
    # process with JAX loaded would start with its parent's peak.
    code = ("import re; import brdffit.io as bio; import brdffit.io.table, brdffit.io.alta; "
            "r = lambda: int(re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)) * 1024; "
            f"before = r(); m = bio.load({str(path)!r}); print((r() - before) / {path.stat().st_size}, m.n)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    ratio, n = run.stdout.split()
    return float(ratio), int(n)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads the peak memory from /proc (Linux)")
def test_text_readers_take_a_small_multiple_of_the_file(tmp_path):
    """docs/cli.md: a numeric table about 4.4 times its size at the peak, ALTA text 3.3, a table read cell by cell
    8-10, a brdffit HDF5 file about 3 (measured 4.3, 3.4, 9.5 and 3.5 on these 11-26 MB files, 4.4, 3.3, 8.1 and 2.7
    on 34-80 MB ones); the bounds leave room for the allocator."""
    import brdffit.io as bio
    from brdffit.measurements import Measurements

    n = 200_000
    rng = np.random.default_rng(0)
    m = Measurements(rng.uniform(0, 1.3, n), rng.uniform(0, 6, n), rng.uniform(0, 1.3, n), rng.uniform(0, 6, n),
                     rng.uniform(0.1, 0.5, (n, 3)))
    table, alta, h5 = tmp_path / "m.csv", tmp_path / "m.alta", tmp_path / "m.h5"
    bio.save(m, table)
    bio.write_alta(m, alta)
    bio.save(m, h5)
    cells = tmp_path / "cells.csv"
    cells.write_bytes(table.read_bytes() + b"10,10,10,10,-,0.2,0.2\n")  # a missing marker: read cell by cell
    for path, bound in ((table, 6.0), (alta, 6.0), (cells, 14.0), (h5, 6.0)):
        ratio, read = _peak_increase(path)
        assert read >= n and 1.0 < ratio < bound, (path.name, ratio)  # above 1: the file itself is held



# A thread of its own (an arena of its own, as XLA's workers have) allocates 48 MiB with malloc, writes it and frees
# it, six times; the last five's page faults are printed. NumPy is not used: it asks for huge pages.
_REALLOCATE = """
import ctypes, resource, sys, threading
from brdffit import _memory

kept = _memory.keep_freed_memory() if sys.argv[1] == "keep" else False
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes, libc.free.argtypes = ctypes.c_void_p, [ctypes.c_size_t], [ctypes.c_void_p]
size = 48 << 20
faults = []

def touch():
    block = libc.malloc(size)
    ctypes.memset(block, 1, size)
    libc.free(block)

def work():
    touch()
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    for _ in range(5):
        touch()
    faults.append(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)

thread = threading.Thread(target=work)
thread.start()
thread.join()
print(kept, faults[0])
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc options (brdffit._memory)")
def test_the_console_scripts_malloc_reuses_freed_memory_instead_of_faulting_it_in_again():
    """A 48 MiB block allocated, written and freed six times in a thread: by default glibc maps it anew each time
    and its pages fault in again (12,288 pages of 4 KiB each time: 61,440 faults; at least 120 with 2 MiB pages);
    with `keep_freed_memory` (the console script's process, `brdffit.cli.run`) it reuses the first block's pages."""
    runs = {}
    for mode in ("keep", "default"):
        run = subprocess.run([sys.executable, "-c", _REALLOCATE, mode], cwd=ROOT, capture_output=True, text=True,
                             timeout=120, env={k: v for k, v in os.environ.items()
                                               if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"})
        assert run.returncode == 0, run.stderr[-2000:]
        kept, faults = run.stdout.split()
        runs[mode] = (kept == "True", int(faults))
    if not runs["keep"][0]:
        pytest.skip("not glibc: no mallopt")
    assert runs["default"][1] >= 120, runs
    assert runs["keep"][1] < 100, runs
