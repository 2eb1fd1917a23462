"""Benchmark of `brdffit.fit_database` (issue 19): a database of small materials on a LocalCluster, throughput
against the number of workers, after compilation (docs/benchmarks.md).

The database: ``--materials`` files (default 1,000) of ``--samples`` uniform samples (default 2,000) of Lambert +
GGX materials with 1% relative noise, each its own brdffit HDF5 file. For each worker count a LocalCluster of
single-threaded worker processes is started, every worker compiles on a warm-up run of one batch per worker (its
rows are discarded), then the whole database is fitted into a CSV table; the wall time of that run is the figure,
beside the time of the ``fit_many`` calls a worker (the rows' ``time`` summed, over the workers): what the wall
time holds beyond it is reading, rows, scheduling, idle workers and the table.
A serial baseline fits ``--serial`` of the materials one by one with `brdffit.fit` in this process, which then
measures the cost of reading a file (`read_cost`).

    python scripts/bench_batch.py [--materials 1000] [--samples 2000] [--workers 1,2] [--batch 128] [--serial 50]
                                  [--data DIR]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from brdffit.distributed import DEFAULT_BATCH  # noqa: E402  (after the platform is set; loads neither JAX nor Dask)

SPEC = "lambert+ggx"


def material(i: int, samples: int):
    """Material ``i`` of the database: Lambert + GGX with parameters varied by ``i``, ``samples`` uniform samples
    with 1% relative noise seeded by ``i`` (`brdffit.Measurements`)."""
    from brdffit import models, synth

    truth = models.get(SPEC, alpha=0.05 + 0.4 * (i % 97) / 97, ks=[0.05 + 0.3 * (i % 13) / 13] * 3,
                       rho_d=[0.2 + 0.6 * (i % 7) / 7] * 3)
    return synth.generate(truth, n=samples, noise="relative:0.01", seed=i)


def make_database(folder: Path, count: int, samples: int) -> list[str]:
    """``count`` materials (`material`), one HDF5 file each (a file already in ``folder`` is kept: it holds what
    would be written, the data seeded by the material's number)."""
    from brdffit import io

    paths = []
    for i in range(count):
        path = folder / f"m{i:04d}.h5"
        if not path.exists():
            io.save(material(i, samples), path)
        paths.append(str(path))
    return paths


def run(paths: list[str], workers: int, batch: int, cache: str, out: Path) -> dict:
    """Fit the database on a fresh LocalCluster of ``workers`` processes, after a warm-up that compiles."""
    from distributed import Client

    from brdffit import fit_database
    from brdffit.distributed.database import local_cluster

    with local_cluster(workers) as cluster, Client(cluster) as client:
        start = time.perf_counter()
        fit_database(paths[:batch * workers], SPEC, client=client, batch=batch, cache_dir=cache)
        warm = time.perf_counter() - start
        start = time.perf_counter()
        rows = fit_database(paths, SPEC, client=client, batch=batch, out=out, resume=False, cache_dir=cache)
        wall = time.perf_counter() - start
    converged = sum(row["status"] in ("converged", "converged-at-bound") for row in rows)
    return {"workers": workers, "warm-up": warm, "wall": wall, "throughput": len(rows) / wall,
            "median time": statistics.median(row["time"] for row in rows), "converged": converged,
            "rows": len(rows), "fitting": sum(row["time"] for row in rows) / workers}


def serial(paths: list[str]) -> dict:
    """One `brdffit.fit` after another in this process (the first, which compiles, not counted)."""
    import brdffit
    from brdffit import io

    brdffit.fit(io.load(paths[0]), SPEC)
    times = []
    for path in paths:
        m = io.load(path)
        start = time.perf_counter()
        brdffit.fit(m, SPEC)
        times.append(time.perf_counter() - start)
    return {"fits": len(paths), "median": statistics.median(times), "throughput": 1 / statistics.median(times)}


def read_cost(paths: list[str], batch: int) -> dict:
    """Seconds a file of reading (in this process, with JAX loaded and a fit compiled, as on a worker): `io.load`
    one file after another (one inspecting child a file) and `read_sources` a batch at a time (one child a batch,
    as a task reads), the best of three passes over the same files."""
    from brdffit import io
    from brdffit.distributed.sources import Source, read_sources

    def best(read) -> float:
        times = []
        for _ in range(3):
            start = time.perf_counter()
            read()
            times.append(time.perf_counter() - start)
        return min(times) / len(paths)

    return {"load": best(lambda: [io.load(path) for path in paths]),
            "batch": best(lambda: [read_sources([Source(p) for p in paths[i:i + batch]])
                                   for i in range(0, len(paths), batch)])}


def machine() -> str:
    """When and where: the UTC time, the cores and the load average (the host may be shared)."""
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return (f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, {os.cpu_count()} cores, load average "
            f"{load} (1, 5, 15 min)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--materials", type=int, default=1000)
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    parser.add_argument("--batch", type=int, default=DEFAULT_BATCH, help=f"default {DEFAULT_BATCH} (fit_database's)")
    parser.add_argument("--serial", type=int, default=50, help="materials fitted one by one for the baseline")
    parser.add_argument("--data", type=Path, help="a folder for the database, whose files a later run reuses "
                                                  "(default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        tmp = Path(tmp)
        data = (args.data or tmp / "data") / f"samples-{args.samples}"
        data.mkdir(parents=True, exist_ok=True)
        print(machine())
        start = time.perf_counter()
        paths = make_database(data, args.materials, args.samples)
        print(f"{len(paths)} materials of {args.samples} samples ready (written or kept) in "
              f"{time.perf_counter() - start:.1f} s")
        cache = str(tmp / "jax-cache")
        if args.serial:
            base = serial(paths[:args.serial])
            print(f"serial fit(): median {base['median']:.3f} s a material over {base['fits']} "
                  f"({base['throughput']:.2f} materials/s)")
            read = read_cost(paths[:2 * args.batch], args.batch)
            print(f"reading a file: io.load {1e3 * read['load']:.1f} ms, a task's batch of {args.batch} "
                  f"{1e3 * read['batch']:.1f} ms")
        print("| workers | warm-up (compiles) | wall, all materials | materials/s | median time a material "
              "(its share of its batch) | fit_many a worker (wall beyond it) | converged |")
        print("|---|---|---|---|---|---|---|")
        for workers in (int(w) for w in args.workers.split(",")):
            r = run(paths, workers, args.batch, cache, tmp / f"results-{workers}.csv")
            print(f"| {r['workers']} | {r['warm-up']:.1f} s | {r['wall']:.1f} s | {r['throughput']:.1f} | "
                  f"{r['median time']:.3f} s | {r['fitting']:.1f} s ({r['wall'] - r['fitting']:.1f} s) | "
                  f"{r['converged']}/{r['rows']} |", flush=True)
            print(f"<!-- after {workers} worker(s): {machine()} -->", flush=True)


if __name__ == "__main__":
    main()
