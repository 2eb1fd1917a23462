"""Benchmark of issue 5: 32 walkers x 5000 steps on 5,000 samples of Lambert + Cook-Torrance (shared roughness,
f0 held fixed), noise estimated per channel. Target: <= 60 s on the 2-core CPU.

Usage: python scripts/bench_posterior.py [--steps 5000]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax

import brdffit
from brdffit import fit, models, synth
from brdffit.posterior import posterior


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    args = parser.parse_args()
    truth = models.get("lambert+cook-torrance", rho_d=[0.3, 0.2, 0.1], ks=[0.8, 0.7, 0.6], m=0.15, f0=0.04)
    data = synth.generate(truth, pattern="half-diff", n=5000, noise="relative:0.01", seed=0)
    result = fit(data, "lambert+cook-torrance", fixed=["f0"], loss="sigma")
    posterior(result, data, nwalkers=32, nsteps=20, progress=False)  # compile outside the timing
    t0 = time.perf_counter()
    post = posterior(result, data, nwalkers=32, nsteps=args.steps, progress=False)
    elapsed = time.perf_counter() - t0
    d = post.diagnostics
    print(f"{time.strftime('%Y-%m-%d')}, {platform.machine()}, {os.cpu_count()} cores, JAX {jax.__version__} "
          f"({jax.default_backend()}), brdffit {brdffit.__version__}")
    print(f"32 walkers x {args.steps} steps, 5000 samples x 3 channels, {len(post.names)} dimensions: "
          f"{elapsed:.1f} s (sampling {post.wall_time:.1f} s); acceptance {d['acceptance_fraction']:.3f}, "
          f"tau max {d['tau_max']:.1f}, min ESS {d['ess_min']:.0f}, max split R-hat {d['r_hat_max']:.4f}")


if __name__ == "__main__":
    main()
