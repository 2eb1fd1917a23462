"""The engine's throughput on many small materials, in one process, on whatever device JAX uses (issue 19).

`brdffit.fit_database` hands each Dask task a batch of equally shaped materials, which one `brdffit.fit_many`
fits; this measures that call alone, without Dask, reading or a second process, so that the engine's own cost a
material can be compared across code versions, batch sizes and devices (a CPU core, a GPU). The materials are
those of ``scripts/bench_batch.py`` (Lambert + GGX, ``--samples`` uniform samples, 1% relative noise), made in
memory. For each batch size, one batch is fitted first (it compiles, not counted), then ``--materials`` materials
in batches of that size; each figure is the median over ``--repeats`` such passes. The baseline, measured in the
same run, is `brdffit.fit` one material after another.

    python scripts/bench_fit_many.py [--materials 256] [--samples 2000] [--batch 32] [--serial 16] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

from bench_batch import SPEC, machine, material


def passes(items: list, batch: int, repeats: int) -> list[float]:
    """Seconds a material of `brdffit.fit_many` over ``items`` in batches of ``batch``, one figure a pass."""
    import brdffit

    brdffit.fit_many(items[:batch], SPEC)  # compiles
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        results = [r for i in range(0, len(items), batch) for r in brdffit.fit_many(items[i:i + batch], SPEC)]
        out.append((time.perf_counter() - start) / len(items))
        converged = sum(r.status in ("converged", "converged-at-bound") for r in results)
        if converged != len(items):
            print(f"  ({len(items) - converged} of {len(items)} did not converge)")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--materials", type=int, default=256)
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--batch", default="32", help="comma-separated batch sizes")
    parser.add_argument("--serial", type=int, default=16, help="materials fitted one by one for the baseline")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    import jax

    import brdffit

    print(machine(), f"JAX {jax.__version__} on {jax.devices()[0].device_kind}")
    items = [material(i, args.samples) for i in range(args.materials)]
    print("| what | ms a material (median) | passes | materials/s |")
    print("|---|---|---|---|")
    if args.serial:
        brdffit.fit(items[0], SPEC)  # compiles
        times = []
        for m in items[:args.serial]:
            start = time.perf_counter()
            brdffit.fit(m, SPEC)
            times.append(time.perf_counter() - start)
        median = statistics.median(times)
        print(f"| serial `fit()`, {args.serial} materials | {1e3 * median:.1f} | 1 | {1 / median:.1f} |")
    for batch in (int(b) for b in args.batch.split(",")):
        figures = passes(items, batch, args.repeats)
        median = statistics.median(figures)
        print(f"| `fit_many`, batches of {batch} | {1e3 * median:.1f} | "
              f"{', '.join(f'{1e3 * f:.1f}' for f in figures)} | {1 / median:.1f} |", flush=True)


if __name__ == "__main__":
    main()
