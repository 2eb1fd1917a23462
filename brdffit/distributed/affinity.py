"""The cores of a local cluster shared out among its workers (docs/batch.md).

A LocalCluster's workers are processes that the operating system moves between the cores as it likes; with as many
single-threaded workers as cores, two of them (and XLA's threads in each) often share a core while another waits.
Each pinned to a core of its own, the workers no longer share one core while another waits, and a database is
fitted faster than unpinned (docs/benchmarks.md).
"""

from __future__ import annotations

import os

from distributed import WorkerPlugin

__all__ = ["PinnedCore"]


class PinnedCore(WorkerPlugin):
    """Pins every thread of a worker process, and so the threads it starts later (XLA's among them), to its share
    of the cores: worker k of a LocalCluster of n (its name) gets ``cores[k::n]``, one core each when there are as
    many workers as cores (one worker keeps them all: pinned to one core, a lone worker would lose XLA's use of
    the others).

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
