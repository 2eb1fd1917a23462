"""Fitting a database on Dask (issue 19): a LocalCluster of two worker processes, and a real ``dask scheduler``
with two ``dask worker`` processes of which one is killed mid-run. Every material must end with a row equal to a
serial `brdffit.fit` of it alone.

Equality, as the engine gives it: `fit_many` of one material is `fit` bit for bit, and the same batches give the
same numbers on every run and worker; but a batch of several materials does not give the bits of the serial fits:
its solves stop, within their tolerance, elsewhere on the flat bottom of the cost. Measured on these materials
(300 samples): cost 2.8e-10 relative, parameters 3.4e-4 standard errors apart, standard errors 1.6e-5 and metrics
9.4e-6 relative, step counts different (10 against 5). So a row is equal to the serial fit when its cost agrees to
`COST_RTOL`, each parameter to `PARAM_SIGMAS` of its standard error and every other number but time and steps to
`SERIAL_RTOL`; and a run whose worker was killed is compared with the undisturbed run of the same batches exactly.
The workers run JAX on the CPU with one persistent compilation cache (a temporary folder) shared by every worker
of this file.
"""

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import brdffit
from brdffit import io, models, synth
from brdffit.cli import EXIT_BAD_INPUT, EXIT_NOT_CONVERGED, EXIT_OK, main
from brdffit.distributed import expand_sources, fit_database, read_results, tasks, write_results
from brdffit.distributed.database import local_cluster
from brdffit.distributed.sources import read_sources
from brdffit.distributed.tasks import fit_batch, result_row
from brdffit.io.hdf5 import write_measurements_group

SPEC = "lambert+ggx"
COST_RTOL = 1e-8
PARAM_SIGMAS = 1e-2
SERIAL_RTOL = 1e-4


# ------------------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def jax_on_cpu():
    """Worker processes inherit this environment: JAX on the CPU."""
    before = os.environ.get("JAX_PLATFORMS")
    os.environ["JAX_PLATFORMS"] = "cpu"
    yield
    if before is None:
        os.environ.pop("JAX_PLATFORMS")
    else:
        os.environ["JAX_PLATFORMS"] = before


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("jax-cache"))


def _material(i: int, n: int):
    truth = models.get(SPEC, alpha=0.08 + 0.04 * i, ks=[0.1 + 0.02 * i] * 3)
    return synth.generate(truth, n=n, noise="relative:0.01", seed=100 + i)


@pytest.fixture(scope="module")
def database(tmp_path_factory) -> dict:
    """Eight tiny materials: four files of 300 samples, a multi-material HDF5 file with two groups of 300, two CSV
    files of 240 samples (another shape); and one file that cannot be read. Returns source key -> Measurements
    (None for the bad file)."""
    folder = tmp_path_factory.mktemp("database")
    found = {}
    for i in range(4):
        m = _material(i, 300)
        io.save(m, folder / f"m{i}.h5")
        found[str((folder / f"m{i}.h5").resolve())] = io.load(folder / f"m{i}.h5")
    multi = folder / "texels.h5"
    for i, group in ((4, "texels/a"), (5, "texels/b")):
        m = _material(i, 300)
        io.update_hdf5(multi, group, lambda g, m=m: write_measurements_group(g, m))
        found[f"{multi.resolve()}::{group}"] = io.read_hdf5(multi, group=group)
    for i in (6, 7):
        io.save(_material(i, 240), folder / f"m{i}.csv")
        found[str((folder / f"m{i}.csv").resolve())] = io.load(folder / f"m{i}.csv")
    (folder / "broken.csv").write_text("theta_i,phi_i,theta_o,phi_o,R\n0.1,0,0.2,zero,0.3\n")
    found[str((folder / "broken.csv").resolve())] = None
    return {"folder": folder, "materials": found}


@pytest.fixture(scope="module")
def serial(database) -> dict:
    """Each readable material fitted alone, in this process: the reference rows."""
    return {key: result_row(key, brdffit.fit(m, SPEC), 0.0) for key, m in database["materials"].items()
            if m is not None}


@pytest.fixture(scope="module")
def client(jax_on_cpu):
    """fit_database's own local cluster of two workers (`local_cluster`)."""
    from distributed import Client

    with local_cluster(2) as cluster, Client(cluster) as connected:
        yield connected


def _thread_cores():
    """The cores each thread of this process may run on, after XLA's threads started (run on a worker)."""
    import jax.numpy as jnp

    jnp.ones(3).sum().block_until_ready()
    return sorted({tuple(sorted(os.sched_getaffinity(int(t)))) for t in os.listdir("/proc/self/task")})


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="sharing out the cores needs Linux's affinity and at least two cores")
def test_the_local_cluster_gives_each_worker_its_own_share_of_the_cores(client):
    cores = sorted(os.sched_getaffinity(0))
    shares = client.run(_thread_cores)
    # Every thread of a worker, XLA's too, on that worker's share; the two shares split the cores between them.
    assert all(len(threads) == 1 for threads in shares.values()), shares
    assert sorted(threads[0] for threads in shares.values()) == [tuple(cores[0::2]), tuple(cores[1::2])]


@pytest.fixture(scope="module")
def local_run(database, client, cache, tmp_path_factory):
    """The database fitted on the LocalCluster into an HDF5 table, batches of 3."""
    out = tmp_path_factory.mktemp("local") / "results.h5"
    rows = fit_database(str(database["folder"]), SPEC, client=client, batch=3, out=out, cache_dir=cache)
    return rows, out


def _same(rows) -> list[dict]:
    """Rows with NaN as None, so that equal tables compare equal."""
    return [{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()} for row in rows]


def _assert_rows_equal_serial(rows, database, serial):
    # In the order given, a multi-material file's members in its place.
    assert [row["source"] for row in rows] == sorted(database["materials"])
    for row in rows:
        key = row["source"]
        if database["materials"][key] is None:
            assert row["status"] == "error" and "broken.csv" in row["error"] and "zero" in row["error"], row
            continue
        expected = serial[key]
        assert row["status"] == expected["status"] and row["model"] == SPEC, key
        assert row["n_samples"] == expected["n_samples"]
        for column in ("cost", "aic", "bic"):
            assert row[column] == pytest.approx(expected[column], rel=COST_RTOL), (key, column)
        params = [c for c in expected if f"stderr.{c}" in expected]
        assert len(params) == 8  # rho_d[0..2], ks[0..2], alpha, f0
        for column in params:
            assert abs(row[column] - expected[column]) <= PARAM_SIGMAS * expected[f"stderr.{column}"], (key, column)
        others = [c for c in expected if c not in params and isinstance(expected[c], float)
                  and c not in ("time", "steps", "n_samples", "cost", "aic", "bic")]
        assert len(others) == 8 + 5 * 3  # the standard errors and five metrics per channel
        for column in others:
            assert row[column] == pytest.approx(expected[column], rel=SERIAL_RTOL), (key, column)


# ------------------------------------------------------------------------------------------- local cluster
def test_local_cluster_rows_equal_serial_fits(local_run, database, serial):
    rows, out = local_run
    _assert_rows_equal_serial(rows, database, serial)
    assert sum(row["status"] == "converged" for row in rows) == 8
    stored = read_results(out)
    assert _same(stored) == _same(rows), "the HDF5 table holds exactly the returned rows"
    # The truth is recovered: the fits are fits, not merely equal to each other.
    truth = models.get(SPEC, alpha=0.08 + 0.04 * 3)
    m3 = next(row for row in rows if row["source"].endswith("m3.h5"))
    assert m3["alpha"] == pytest.approx(float(truth.params["alpha"]), rel=0.05)


def test_resume_keeps_done_rows_and_fits_the_rest(local_run, database, serial, client, cache, tmp_path, capsys):
    rows, _ = local_run
    out = tmp_path / "results.csv"
    # An interrupted run: four rows written, one of them a failure that a rerun tries again.
    fitted = [row for row in rows if row["status"] == "converged"]
    done = fitted[:3]
    retried = {"source": fitted[3]["source"], "status": "error", "model": SPEC, "error": "KilledWorker: ..."}
    write_results([*done, retried], out)
    resumed = fit_database(str(database["folder"]), SPEC, client=client, batch=3, out=out, cache_dir=cache,
                           progress=True)
    err = capsys.readouterr().err
    assert "6 fitted (1 failed), 3 already done" in err and "ETA" in err  # the broken file fails again
    by_source = {row["source"]: row for row in resumed}
    for before in done:
        # Kept as it was, its time too: it was not fitted again.
        assert _same([by_source[before["source"]]]) == _same([before])
    assert by_source[retried["source"]]["status"] == "converged"
    _assert_rows_equal_serial(resumed, database, serial)
    header = out.read_text().splitlines()[0].split(",")
    assert header[:4] == ["source", "status", "model", "error"]
    assert {"alpha", "f0", "rho_d[0]", "rho_d[2]", "ks[1]", "stderr.alpha", "rmse_rel[0]"} <= set(header)
    assert _same(read_results(out)) == _same(resumed), "the CSV gives back every number exactly"


def test_failing_fit_gets_its_row_and_spares_the_batch(database, serial, monkeypatch):
    """A batch whose fit_many raises is fitted one material at a time: only the failing one gets an error row
    (the engine has no data that makes it raise, so a stand-in fit_many refuses one marked material)."""
    real_fit_many, real_read = brdffit.fit_many, tasks.read_sources
    keys = [k for k, m in database["materials"].items() if m is not None and m.n == 300][:3]
    poisoned = keys[1]

    def refusing(items, model, **options):
        if any(m.meta.get("poison") for m in items):
            raise FloatingPointError("the solve blew up")
        return real_fit_many(items, model, **options)

    def marking(sources, read_options=None):
        return [read._replace(measurements=read.measurements.replace(meta={"poison": True}))
                if read.source.key == poisoned else read for read in real_read(sources, read_options)]

    monkeypatch.setattr(brdffit, "fit_many", refusing)
    monkeypatch.setattr(tasks, "read_sources", marking)
    rows, members = fit_batch(expand_sources(keys), SPEC, None, {}, None)
    assert [row["source"] for row in rows] == keys and members == []
    assert rows[1] == {"source": poisoned, "status": "error", "model": SPEC,
                       "error": "FloatingPointError: the solve blew up"}
    for row in (rows[0], rows[2]):  # each fitted alone: the serial fit, bit for bit
        assert row == {**serial[row["source"]], "time": row["time"]}


def test_a_batch_beyond_fit_samples_is_fitted_in_equal_parts(database, serial, monkeypatch):
    """A task's fit_many calls hold at most FIT_SAMPLES samples: four materials of 300 samples under a limit of
    700 are fitted as two calls of two, and their rows are those of the serial fits."""
    calls = []
    real_fit_many = brdffit.fit_many

    def counting(items, model, **options):
        calls.append(len(items))
        return real_fit_many(items, model, **options)

    keys = [k for k, m in database["materials"].items() if m is not None and m.n == 300][:4]
    monkeypatch.setattr(brdffit, "fit_many", counting)
    monkeypatch.setattr(tasks, "FIT_SAMPLES", 700)
    rows, _ = fit_batch(expand_sources(keys), SPEC, None, {}, None)
    assert calls == [2, 2]
    _assert_rows_equal_serial(rows, {"materials": {k: database["materials"][k] for k in keys}}, serial)


def test_an_interrupted_run_keeps_every_row_it_received(database, tmp_path, monkeypatch):
    """Ctrl-C in the client: the rows that arrived are in the table (the last within the write interval too)."""
    from brdffit.distributed import database as client_side

    def interrupted(client, todo, model, batch, read_options, fit_options, cache, record):
        for i, source in enumerate(todo[:2]):
            record.add([{"source": source.key, "status": "converged", "model": SPEC, "error": "", "alpha": 0.1 * i}])
        raise KeyboardInterrupt

    monkeypatch.setattr(client_side, "_run", interrupted)
    out = tmp_path / "results.csv"
    with pytest.raises(KeyboardInterrupt):
        fit_database(str(database["folder"]), SPEC, client=object(), out=out)
    assert [(row["status"], row["alpha"]) for row in read_results(out)] == [("converged", 0.0), ("converged", 0.1)]


def test_selection_per_material_is_select(database):
    """A model given as candidates (``"auto"`` gives the standard ones) runs `brdffit.select` on each material."""
    from brdffit import select

    key = next(k for k in database["materials"] if k.endswith("m0.h5"))
    candidates = ("lambert", SPEC)
    (row,), _ = fit_batch(expand_sources(key), candidates, None, {}, None)
    chosen = select(database["materials"][key], candidates)
    assert chosen.chosen == SPEC == row["model"] and row["status"] == chosen.result.status
    assert row["alpha"] == float(chosen.result.params["alpha"]) and row["bic"] == chosen.result.bic


def test_cli_batch_on_a_running_scheduler(database, client, cache, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", cache)
    out = tmp_path / "texels.parquet"
    source = str(database["folder"] / "texels.h5")
    code = main(["batch", source, "--model", SPEC, "--out", str(out), "--scheduler", client.scheduler.address,
                 "--json"])
    assert code == EXIT_OK, capsys.readouterr().err
    printed = json.loads(capsys.readouterr().out)
    assert printed == {"out": str(out), "materials": 2, "statuses": {"converged": 2}}
    rows = read_results(out)
    assert [row["source"].rsplit("::", 1)[1] for row in rows] == ["texels/a", "texels/b"]
    assert all(isinstance(row["alpha"], float) for row in rows)
    # The unreadable file makes the exit code 1, its row names the problem.
    code = main(["batch", str(database["folder"] / "broken.csv"), "--model", SPEC, "--out",
                 str(tmp_path / "bad.csv"), "--scheduler", client.scheduler.address, "--quiet"])
    assert code == EXIT_NOT_CONVERGED
    assert read_results(tmp_path / "bad.csv")[0]["status"] == "error"


@pytest.mark.parametrize("argv, message", [
    (["--out", "r.csv", "--workers", "0"], "--workers: 0 is outside the allowed range: an integer >= 1"),
    (["--out", "r.csv", "--batch", "0"], "--batch: 0 is outside the allowed range: an integer >= 1"),
    (["--out", "r.csv", "--fixed", "alpha=7"], "--fixed alpha=7: outside the allowed range of alpha"),
    (["--out", "r.csv", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers sizes the local cluster"),
    (["--out", "r.txt"], "--out: r.txt: a results table is .h5, .hdf5, .csv, .parquet, not '.txt'"),
    (["--out", "r.csv", "--model", "lambert+nonsense"], "nonsense"),
])
def test_cli_batch_refuses_bad_options(argv, message, database, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["batch", str(database["folder"]), "--model", SPEC, *argv]) == EXIT_BAD_INPUT
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir()), "nothing written"


# ------------------------------------------------------------------------------------------- tables, sources
def test_tables_round_trip_and_refuse_what_they_cannot_read(tmp_path, monkeypatch):
    rows = [{"source": "a.h5", "status": "converged", "model": SPEC, "error": "", "alpha": 0.1 + 1e-17,
             "rho_d[0]": 1 / 3},
            {"source": "b, with a comma.h5", "status": "error", "model": SPEC, "error": "FormatError: \"x\"\nline"}]
    for ext in (".h5", ".csv", ".parquet"):
        write_results(rows, tmp_path / f"t{ext}")
        back = read_results(tmp_path / f"t{ext}")
        assert [r["source"] for r in back] == ["a.h5", "b, with a comma.h5"] and back[1]["error"] == rows[1]["error"]
        assert back[0]["alpha"] == rows[0]["alpha"] and back[0]["rho_d[0]"] == 1 / 3, ext
        assert math.isnan(back[1]["alpha"]) and math.isnan(back[0]["time"]), ext
    with pytest.raises(ValueError, match=r"t\.json: a results table is"):
        write_results(rows, tmp_path / "t.json")
    (tmp_path / "n.csv").write_text("source,status,alpha\na,converged,0.1x\n")
    with pytest.raises(io.FormatError, match=r"n\.csv: line 2, column alpha: '0\.1x' is not a number"):
        read_results(tmp_path / "n.csv")
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # pyarrow not installed
    with pytest.raises(ImportError, match=r"pip install 'brdffit\[parquet\]'"):
        write_results(rows, tmp_path / "u.parquet")
    with pytest.raises(ImportError, match="needs pyarrow"):
        fit_database([], SPEC, out=tmp_path / "u.parquet")  # refused before any source is read


def test_sources_expand_globs_folders_and_material_groups(database):
    folder = database["folder"]
    keys = [s.key for s in expand_sources(str(folder))]
    assert keys == sorted(str(p.resolve()) for p in folder.iterdir())
    assert [s.key for s in expand_sources([str(folder / "m*.csv"), str(folder / "m6.csv")])] == [
        str((folder / "m6.csv").resolve()), str((folder / "m7.csv").resolve())]
    texels = expand_sources(str(folder / "texels.h5"))
    assert [s.group for s in texels] == [None], "the client opens no file"
    (whole,) = read_sources(texels)
    assert [m.group for m in whole.members] == ["texels/a", "texels/b"] and whole.measurements is None
    named = read_sources(expand_sources([f"{folder / 'texels.h5'}::/texels/b", f"{folder / 'texels.h5'}::c",
                                         str(folder / "m0.h5"), str(folder / "broken.csv")]))
    assert named[0].measurements.n == 300 and "no group /c" in named[1].error
    assert named[2].measurements.n == 300 and "cannot read 'zero' as a number" in named[3].error
    with pytest.raises(FileNotFoundError, match="no file matches"):
        expand_sources(str(folder / "*.binary"))


# ------------------------------------------------------------------------------------ scheduler + dead worker
@pytest.fixture
def scheduler(jax_on_cpu, tmp_path):
    """A `dask scheduler` and two `dask worker` processes on 127.0.0.1 (ports chosen by the scheduler, found in its
    scheduler file), always killed at the end."""
    from distributed import Client

    dask = str(Path(sys.executable).with_name("dask"))
    info = tmp_path / "scheduler.json"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(info)], **quiet)]
    try:
        deadline = time.monotonic() + 30
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert info.exists(), "the scheduler did not start within 30 s"
        for i in range(2):
            procs.append(subprocess.Popen([dask, "worker", "--scheduler-file", str(info), "--host", "127.0.0.1",
                                           "--nthreads", "1", "--no-nanny", "--no-dashboard", "--name", f"w{i}"],
                                          **quiet))
        with Client(scheduler_file=str(info), timeout="30s") as connected:
            connected.wait_for_workers(2, timeout=60)
            yield connected, procs[1:]
    finally:
        for proc in procs:
            proc.kill()
        for proc in procs:
            proc.wait(timeout=10)


def test_killed_worker_loses_no_result(scheduler, local_run, database, serial, cache, tmp_path):
    connected, workers = scheduler
    pids = connected.run(os.getpid)  # worker address -> process id
    assert sorted(pids.values()) == sorted(p.pid for p in workers)
    killed = {}

    def kill_a_busy_worker():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            for address, keys in connected.processing().items():
                if any("fit_batch" in str(key) for key in keys):
                    os.kill(pids[address], signal.SIGKILL)
                    killed.update(address=address, keys=list(keys))
                    return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
    killer.start()
    out = tmp_path / "results.h5"
    rows = fit_database(str(database["folder"]), SPEC, client=connected, batch=3, out=out, cache_dir=cache)
    killer.join(timeout=5)
    assert killed, "no worker was killed while it fitted a batch"
    assert killed["address"] not in connected.scheduler_info()["workers"], "the killed worker is gone"
    _assert_rows_equal_serial(rows, database, serial)
    assert _same(read_results(out)) == _same(rows)
    undisturbed, _ = local_run  # the same batches on the LocalCluster: the same numbers, bit for bit
    assert _same({**row, "time": 0} for row in rows) == _same({**row, "time": 0} for row in undisturbed)


def test_batches_are_cut_evenly_over_the_workers():
    from brdffit.distributed.database import cut

    sizes = lambda items, batch, workers: [len(group) for group in cut(items, batch, workers)]  # noqa: E731
    assert sizes(list(range(200)), 32, 2) == [25] * 8  # not 6 x 32 + 8: 7 tasks on 2 workers end 4 against 3
    assert sizes(list(range(1000)), 32, 2) == [32] * 8 + [31] * 24
    assert sizes(list(range(1000)), 32, 1) == [32] * 8 + [31] * 24  # even sizes on one worker too
    assert sizes(list(range(100)), 32, 3) == [17] * 4 + [16] * 2
    assert sizes(list(range(3)), 32, 4) == [1, 1, 1] and cut([], 32, 2) == []
    assert [x for group in cut(list(range(77)), 5, 3) for x in group] == list(range(77))  # the order is kept
    assert max(sizes(list(range(77)), 5, 3)) <= 5
