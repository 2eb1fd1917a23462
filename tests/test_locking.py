"""Records written by concurrent commands are never lost or torn: the folder lock
(`brdffit.io.locking.locked`) and what holds it (`update_hdf5`, ``exports.json``, a `brdffit fit` output folder, a
posterior chain), tested with processes racing."""

import json
import os
import shutil
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from brdffit import cli
from brdffit.output_folder import STAGE_MARK
from brdffit.export import records
from brdffit.io import locking
from brdffit.io.locking import LockTimeout, locked

ROOT = Path(__file__).resolve().parents[1]
PLASTIC = ROOT / "data" / "synthetic" / "plastic.h5"
WRITERS = 8
# subprocess.Popen forks before exec; JAX (loaded by other tests of the worker) warns of any fork.
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")


def race(tmp_path, body: str, n: int = WRITERS, timeout: float = 300) -> None:
    """Run ``body`` in ``n`` Python processes at once (``WRITER`` is each one's number, ``FOLDER`` the test's
    folder); they start together once all have imported what they need. Fails unless every one exits 0."""
    go = tmp_path / "go"
    script = tmp_path / "writer.py"
    script.write_text("import os, sys, time\nfrom pathlib import Path\nWRITER, FOLDER = int(sys.argv[1]), "
                      "Path(sys.argv[2])\n" + textwrap.dedent(body).replace("# START", f"""
while not os.path.exists({str(go)!r}):
    time.sleep(0.001)
"""))
    runs = [subprocess.Popen([sys.executable, str(script), str(i), str(tmp_path)], stderr=subprocess.PIPE, text=True)
            for i in range(n)]
    time.sleep(0.5)  # let them import
    go.touch()
    for run in runs:
        _, err = run.communicate(timeout=timeout)
        assert run.returncode == 0, err[-3000:]


# ------------------------------------------------------------------------------------------------ the lock
def test_racing_read_modify_writes_under_the_lock_lose_nothing(tmp_path):
    counter = tmp_path / "counter.json"
    counter.write_text(json.dumps({"count": 0, "writers": []}))
    race(tmp_path, f"""
        import json
        from brdffit.io._common import atomic_path
        from brdffit.io.locking import locked
        path = Path({str(counter)!r})
        # START
        for k in range(10):
            with locked(path):
                state = json.loads(path.read_text())
                time.sleep(0.002)  # another writer would read the same state meanwhile without the lock
                state["count"] += 1
                state["writers"].append([WRITER, k])
                with atomic_path(path) as tmp:
                    tmp.write_text(json.dumps(state))
    """)
    state = json.loads(counter.read_text())
    assert state["count"] == 10 * WRITERS
    assert sorted(map(tuple, state["writers"])) == [(w, k) for w in range(WRITERS) for k in range(10)]


def test_a_lock_is_reentrant_in_a_thread(tmp_path):
    path = tmp_path / "f.json"
    with locked(path):
        with locked(tmp_path / "other.json", shared=True):  # the same folder: held already
            with locked(path):
                pass
    with locked(path, shared=True):
        with pytest.raises(RuntimeError, match="an exclusive lock asked for inside a shared one"):
            with locked(path):
                pass


def test_threads_of_one_process_take_turns(tmp_path):
    inside, overlaps = [], []

    def work():
        for _ in range(20):
            with locked(tmp_path / "f"):
                inside.append(1)
                overlaps.append(len(inside) > 1)
                time.sleep(0.0005)
                inside.pop()

    threads = [threading.Thread(target=work) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    assert len(overlaps) == 80 and not any(overlaps)


def hold_lock(folder: Path, seconds: float):
    """A child process that holds ``folder``'s lock for ``seconds``; returns once it holds it."""
    code = ("import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDONLY); fcntl.flock(fd, fcntl.LOCK_EX); "
            "print('held', flush=True); time.sleep(float(sys.argv[2]))")
    child = subprocess.Popen([sys.executable, "-c", code, str(folder), str(seconds)], stdout=subprocess.PIPE,
                             text=True)
    assert child.stdout.readline().strip() == "held"
    return child


def test_a_lock_held_too_long_is_a_timeout_naming_the_folder(tmp_path):
    child = hold_lock(tmp_path, 60)
    try:
        start = time.monotonic()
        with pytest.raises(LockTimeout, match=f"{tmp_path}: another process has held the lock"):
            with locked(tmp_path / "f", timeout=0.3):
                pass
        assert time.monotonic() - start < 30  # a hang guard: the wait ends at its 0.3 s timeout
    finally:
        child.kill()
        child.wait()
    with locked(tmp_path / "f", timeout=30):  # free again once the holder is gone
        pass
    assert isinstance(LockTimeout("x"), OSError) and isinstance(LockTimeout("x"), ValueError)


def test_a_folder_replaced_while_waiting_is_locked_anew(tmp_path):
    """``brdffit fit --force`` swaps its output folder for a new one: a writer waiting on the old folder's lock
    takes the new folder's once it has the old one."""
    folder = tmp_path / "out"
    folder.mkdir()
    child = hold_lock(folder, 1.0)
    got = []

    def wait_for_it():
        with locked(folder / "exports.json"):
            got.append(os.stat(folder).st_ino)
            got.append({key[1] for key, held in locking._HELD.items() if held.count})

    waiter = threading.Thread(target=wait_for_it)
    waiter.start()
    time.sleep(0.2)
    folder.rename(tmp_path / "old")
    folder.mkdir()
    waiter.join(timeout=60)
    child.wait(timeout=60)
    assert got and got[0] == os.stat(folder).st_ino and got[0] in got[1]


# ------------------------------------------------------------------------------------------------ HDF5 files
def test_racing_updates_of_one_result_file_keep_every_group(tmp_path):
    import brdffit.io as bio
    from brdffit.measurements import Measurements

    h5 = tmp_path / "result.h5"
    m = Measurements(np.full(5, 0.3), 0.0, np.full(5, 0.5), np.pi, np.full(5, 0.2))
    bio.save(m, h5)
    race(tmp_path, f"""
        from brdffit.io.hdf5 import update_hdf5
        # START
        for k in range(3):
            update_hdf5({str(h5)!r}, f"fits/w{{WRITER}}-{{k}}", lambda g: g.attrs.__setitem__("writer", WRITER))
    """)
    with h5py.File(h5, "r") as f:
        assert sorted(f["fits"]) == sorted(f"w{w}-{k}" for w in range(WRITERS) for k in range(3))
        assert all(f[f"fits/w{w}-0"].attrs["writer"] == w for w in range(WRITERS))
    assert np.array_equal(bio.load(h5).values, m.values)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["go", "result.h5", "writer.py"]  # no temporary left


# ------------------------------------------------------------------------------------------------ exports.json
def test_racing_exports_keep_every_record(tmp_path):
    folder = tmp_path / "plastic.brdffit"
    folder.mkdir()
    (folder / "result.h5").write_bytes(b"")  # record() only needs a fit output folder's two names
    (folder / "result.json").write_text("{}")
    race(tmp_path, f"""
        from brdffit.export import records
        # The record of an export, without fitting one: what is raced is the read, merge and write of the file.
        records.ExportRecord.of = classmethod(lambda cls, export, to, out=None: cls(
            target=to, source={{"writer": WRITER, "k": export}}, written="lambert", fitted=None, rms=0.01,
            max_rel=0.02, approximations=(), exact=False, date="2026-12-05T00:00:00+00:00", out=None))
        # START
        for k in range(3):
            records.record({str(folder / "result.h5")!r}, k, "mitsuba")
    """)
    log = records.read(folder / "result.h5")
    assert log.problem is None
    assert sorted((r.source["writer"], r.source["k"]) for r in log.records) == [
        (w, k) for w in range(WRITERS) for k in range(3)]


# ------------------------------------------------------------------------------------------------ the commands
def brdffit(*args, **popen):
    return subprocess.Popen([sys.executable, "-m", "brdffit.cli", *map(str, args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, **popen)


def finish(runs, timeout=600):
    out = []
    for run in runs:
        _, err = run.communicate(timeout=timeout)
        out.append((run.returncode, err))
    return out


def complete_result(out: Path) -> str:
    """The spec of the one complete result in ``out``: result.json and the fit in result.h5 agree."""
    spec = json.loads((out / "result.json").read_text())["model"]
    with h5py.File(out / "result.h5", "r") as f:
        assert list(f["fits"]) == [spec.replace("/", "_")]
    assert (out / "summary.txt").is_file()
    assert not any(STAGE_MARK in p.name for p in out.parent.iterdir())
    return spec


@pytest.mark.slow
def test_two_fits_into_one_folder_without_force_write_one_and_refuse_the_other(tmp_path):
    out = tmp_path / "plastic.brdffit"
    runs = [brdffit("fit", PLASTIC, "--model", model, "--no-report", "--quiet", "--out", out)
            for model in ("lambert+ggx", "lambert+blinn-phong")]
    results = finish(runs)
    codes = sorted(code for code, _ in results)
    assert codes == [cli.EXIT_OK, cli.EXIT_BAD_INPUT], results
    refused = next(err for code, err in results if code == cli.EXIT_BAD_INPUT)
    assert "another process wrote a result" in refused or "holds an earlier result" in refused, refused
    assert "Traceback" not in refused
    complete_result(out)


@pytest.mark.slow
def test_two_fits_into_one_folder_with_force_leave_one_complete_result(tmp_path):
    out = tmp_path / "plastic.brdffit"
    runs = [brdffit("fit", PLASTIC, "--model", model, "--no-report", "--quiet", "--force", "--out", out)
            for model in ("lambert+ggx", "lambert+blinn-phong")]
    results = finish(runs)
    assert [code for code, _ in results] == [cli.EXIT_OK, cli.EXIT_OK], results
    assert complete_result(out) in ("lambert+ggx", "lambert+blinn-phong")


@pytest.mark.slow
def test_racing_posteriors_of_one_chain_store_the_chain_of_one_run(tmp_path):
    """Three `brdffit posterior` on one result at once: the stored chain is the one a single run stores, step for
    step (each step is stored only where the chain still stands where its process read it). The fit and the
    single run are made in this process (`brdffit.cli.main`, the command's own code; nothing races there); the
    three that race are commands of their own."""
    base = tmp_path / "base"
    assert cli.main(["fit", str(PLASTIC), "--model", "lambert+ggx", "--no-report", "--quiet", "--out",
                     str(base)]) == cli.EXIT_OK
    alone, raced = tmp_path / "alone", tmp_path / "raced"
    shutil.copytree(base, alone)
    shutil.copytree(base, raced)
    steps = ["--walkers", "22", "--steps", "60", "--quiet"]
    assert cli.main(["posterior", str(alone / "result.h5"), *steps]) == cli.EXIT_OK
    results = finish([brdffit("posterior", raced / "result.h5", *steps) for _ in range(3)])
    assert all(code == cli.EXIT_OK and "Traceback" not in err for code, err in results), results
    with h5py.File(alone / "result.h5", "r") as a, h5py.File(raced / "result.h5", "r") as b:
        one, many = a["posteriors/lambert+ggx/chain"], b["posteriors/lambert+ggx/chain"]
        assert one.attrs["iteration"] == many.attrs["iteration"] == 60
        assert np.array_equal(one["chain"][:60], many["chain"][:60])
        assert np.array_equal(one["log_prob"][:60], many["log_prob"][:60])
        assert np.array_equal(one["accepted"][...], many["accepted"][...])
        assert "result" in b["posteriors/lambert+ggx"] and "lambert+ggx" in b["fits"]
