"""Killed and interrupted runs (issue 20): an output folder holds either the complete earlier result or the complete
new one after a SIGKILL at any moment, and leaves no staging folder behind once the next run has started; a rerun
never leaves stale files of the earlier result; an earlier result is replaced only with --force."""

import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import brdffit.io as bio
from brdffit.cli import EXIT_BAD_INPUT, EXIT_OK, STAGE_MARK, main, staged_folder
from brdffit.io import update_hdf5
from brdffit.measurements import Measurements

N_KILLS = 24
# subprocess.Popen forks before exec; JAX (loaded by FitResult.load) warns of any fork.
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")


def measurements(n=20_000, seed=0) -> Measurements:
    rng = np.random.default_rng(seed)
    return Measurements(rng.uniform(0, 1.5, n), rng.uniform(0, 6, n), rng.uniform(0, 1.5, n), rng.uniform(0, 6, n),
                        rng.uniform(0.1, 0.5, (n, 3)))


def write_result(folder: Path, tag: str, m: Measurements) -> None:
    """A result set as `brdffit fit` writes it: result.h5 (measurements + /fits/<tag>), result.json, summary.txt."""
    h5 = folder / "result.h5"
    bio.save(m, h5)
    update_hdf5(h5, f"fits/{tag}", lambda g: g.attrs.__setitem__("spec", tag))
    (folder / "result.json").write_text(json.dumps({"model": tag}))
    (folder / "summary.txt").write_text(f"model {tag}\n")


def fork_writer(out: Path, tag: str, m: Measurements) -> int:
    """A child process that writes the result ``tag`` through `staged_folder` (it runs no JAX)."""
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            with staged_folder(out) as stage:
                write_result(stage, tag, m)
            code = 0
        finally:
            os._exit(code)
    return pid


def result_in(out: Path) -> str:
    """The tag of the complete result in ``out``; fails unless its three files describe one and the same fit."""
    assert sorted(os.listdir(out)) == ["result.h5", "result.json", "summary.txt"]
    tag = json.loads((out / "result.json").read_text())["model"]
    assert (out / "summary.txt").read_text() == f"model {tag}\n"
    import h5py

    with h5py.File(out / "result.h5", "r") as f:
        assert list(f["fits"]) == [tag] and f["measurements/values"].shape == (20_000, 3)
    return tag


def test_output_folder_survives_kills_at_many_points(tmp_path):
    out = tmp_path / "result"
    m = measurements()
    with staged_folder(out) as stage:
        write_result(stage, "old", m)
    start = time.perf_counter()
    os.waitpid(fork_writer(out, "timing", m), 0)
    duration = time.perf_counter() - start  # one whole write, about 0.1 s
    expected, seen = "timing", set()
    for k in range(N_KILLS):
        tag = f"new{k}"
        pid = fork_writer(out, tag, m)
        time.sleep(duration * 1.2 * k / N_KILLS)  # kill points spread over the whole write
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
        found = result_in(out)
        assert found in (expected, tag)  # the earlier result or the new one, complete either way
        expected = found
        seen.add("killed" if os.WIFSIGNALED(status) else "finished")
        seen.add("replaced" if found == tag else "kept")
    assert {"killed", "kept", "replaced"} <= seen  # kills landed before and after the swap
    os.waitpid(fork_writer(out, "last", m), 0)
    assert result_in(out) == "last"
    assert [p.name for p in tmp_path.iterdir()] == ["result"]  # the killed runs' staging folders are gone


def test_a_failed_write_keeps_the_earlier_result(tmp_path):
    out = tmp_path / "result"
    m = measurements(seed=1)
    with staged_folder(out) as stage:
        write_result(stage, "old", m)
    with pytest.raises(RuntimeError, match="disk full"):
        with staged_folder(out) as stage:
            (stage / "result.json").write_text("{}")
            raise RuntimeError("disk full")
    assert result_in(out) == "old" and [p.name for p in tmp_path.iterdir()] == ["result"]


# ----------------------------------------------------------------------------------- the real command
def brdffit(args, cwd, env, **popen):
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))

    return subprocess.Popen([sys.executable, "-m", "brdffit.cli", *map(str, args)], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=limit, **popen)


@pytest.fixture(scope="module")
def small_table(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli-kill")
    rng = np.random.default_rng(3)
    n = 300
    m = Measurements(rng.uniform(0, 1.3, n), rng.uniform(0, 6, n), rng.uniform(0, 1.3, n), rng.uniform(0, 6, n),
                     0.3 / np.pi * rng.normal(1.0, 0.01, n))
    bio.save(m, folder / "small.csv")
    return folder / "small.csv"


@pytest.mark.slow
def test_cli_fit_rerun_killed_or_completed_never_mixes_results(small_table, tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "BRDFFIT_CACHE_DIR": str(tmp_path / "cache")}
    out = tmp_path / "o"
    old = brdffit(["fit", small_table, "--model", "lambert", "--no-report", "--posterior", "--walkers", "4",
                   "--steps", "20", "--out", out, "--quiet"], tmp_path, env)
    assert old.wait(timeout=300) == EXIT_OK, old.stderr.read()
    assert sorted(os.listdir(out)) == ["posterior.json", "result.h5", "result.json", "summary.txt"]
    # Without --force the earlier result is refused before anything runs.
    assert main(["fit", str(small_table), "--model", "oren-nayar", "--out", str(out)]) == EXIT_BAD_INPUT
    # Killed as soon as its staging folder appears (while it writes): the earlier result stays whole.
    run = brdffit(["fit", small_table, "--model", "oren-nayar", "--no-report", "--out", out, "--force", "--quiet"],
                  tmp_path, env)
    while not any(STAGE_MARK in p.name for p in tmp_path.iterdir()) and run.poll() is None:
        time.sleep(0.002)
    run.send_signal(signal.SIGKILL)
    run.wait(timeout=60)
    names = sorted(os.listdir(out))
    spec = json.loads((out / "result.json").read_text())["model"]
    assert (names, spec) in ((["posterior.json", "result.h5", "result.json", "summary.txt"], "lambert"),
                             (["result.h5", "result.json", "summary.txt"], "oren-nayar"))
    from brdffit import FitResult

    assert FitResult.load(out / "result.h5").spec == spec
    # Completed with another model: the new set only (no stale posterior.json), no staging folder left.
    run = brdffit(["fit", small_table, "--model", "oren-nayar", "--no-report", "--out", out, "--force", "--quiet"],
                  tmp_path, env)
    assert run.wait(timeout=300) in (0, 1), run.stderr.read()
    assert sorted(os.listdir(out)) == ["result.h5", "result.json", "summary.txt"]
    assert json.loads((out / "result.json").read_text())["model"] == "oren-nayar"
    assert FitResult.load(out / "result.h5").spec == "oren-nayar"
    assert not any(STAGE_MARK in p.name for p in tmp_path.iterdir())
