"""The cores of a local cluster shared out among its workers (docs/batch.md).

A LocalCluster's workers are processes that the operating system moves between the cores as it likes; with as many
single-threaded workers as cores, two of them (and XLA's threads in each) often share a core while another waits.
Each pinned to a core of its own, two workers fitted 1,000 Lambert + GGX materials on the 2-core host in 15.5-16.5 s
against 17.3-18.3 s unpinned (docs/benchmarks.md, issue 19).
"""

from __future__ import annotations

import os

from distributed import WorkerPlugin

__all__ = ["PinnedCore"]


class PinnedCore(WorkerPlugin):
    """Pins every thread of a worker process, and so the threads it starts later (XLA's among them), to its share
    of the cores: worker k of a LocalCluster of n (its name) gets ``cores[k::n]``, one core each when there are as
    many workers as cores (one worker keeps them all: pinned to one core, a lone worker lost XLA's use of the
    other, 24.4 -> 29.6 s).

    Arguments:
        cores: the cores to share out (the client's own affinity, in order).
        workers: the cluster's number of workers (at most ``len(cores)``).
    """

    name = "brdffit-pinned-core"

    def __init__(self, cores, workers: int):
        self.cores, self.workers = tuple(cores), int(workers)

    def setup(self, worker):
        if not isinstance(worker.name, int) or not self.cores:
            return
        share = set(self.cores[worker.name % self.workers::self.workers])
        for thread in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(thread), share)
            except OSError:  # a thread that ended meanwhile
                pass
