"""Calibration study of brdffit.posterior (issue 5): do the credible intervals cover the truth as often as
they claim?

For each of N synthetic data sets (Lambert + Ward, 3 channels, 1000 half-diff samples, Gaussian noise of known
σ = 0.01, a different seed each) it fits by least squares, samples the posterior with noise="known", and
counts how often the 68% and 95% central intervals of each of the 7 parameters contain the true value. The
Laplace intervals (value ± 1 and ± 1.96 stderr) are counted alongside.

Usage: python scripts/posterior_calibration.py [--datasets 60] [--steps 2000]
Prints a Markdown table for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

import brdffit
from brdffit import fit, models, synth
from brdffit.posterior import posterior

TRUTH = dict(rho_d=[0.4, 0.3, 0.2], ks=[0.5, 0.4, 0.3], alpha=0.2)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=60)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--walkers", type=int, default=16)
    args = parser.parse_args()
    truth = models.get("lambert+ward", **TRUTH)
    true_flat = np.concatenate([np.ravel(truth.params[n]) for n in truth.params])
    post68 = post95 = lap68 = lap95 = total = 0
    t0 = time.perf_counter()
    for k in range(args.datasets):
        data = synth.generate(truth, pattern="half-diff", n=1000, noise="gaussian:0.01", seed=1000 + k)
        result = fit(data, "lambert+ward", loss="sigma")
        post = posterior(result, data, nwalkers=args.walkers, nsteps=args.steps, noise="known", progress=False,
                         seed=k)
        for name, true in zip(post.names, true_flat):
            s = post.summary[name]
            post68 += s["q16"] <= true <= s["q84"]
            post95 += s["q2.5"] <= true <= s["q97.5"]
            z = abs(post.fit_values[name] - true) / post.laplace_stderr[name]
            lap68 += z <= 1.0
            lap95 += z <= 1.96
            total += 1
    elapsed = time.perf_counter() - t0
    print(f"{args.datasets} data sets x 7 parameters = {total} intervals, {args.walkers} walkers x {args.steps} "
          f"steps each, {elapsed:.0f} s on {platform.machine()} ({time.strftime('%Y-%m-%d')}, brdffit "
          f"{brdffit.__version__})")
    print()
    print("| interval | nominal | posterior coverage | Laplace coverage |")
    print("|---|---|---|---|")
    print(f"| 68% | 0.68 | {post68 / total:.3f} | {lap68 / total:.3f} |")
    print(f"| 95% | 0.95 | {post95 / total:.3f} | {lap95 / total:.3f} |")


if __name__ == "__main__":
    main()
