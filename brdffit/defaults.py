"""The defaults of the options a user sets most, declared once.

`brdffit.fit`, `brdffit.fit_many`, `brdffit.select`, `brdffit.posterior` and the engine's solver take their defaults
from here, and the CLI its flags' defaults and help texts, so that a default changed here changes everywhere. No
JAX is imported: the CLI builds its parser from these without loading the engine.
"""

from __future__ import annotations

import dataclasses

__all__ = ["FIT", "POSTERIOR", "FitDefaults", "PosteriorDefaults"]


@dataclasses.dataclass(frozen=True)
class FitDefaults:
    """A fit's defaults (`brdffit.fit`, docs/fitting.md).

    Attributes:
        loss: the loss (`brdffit.fitting.losses.LOSSES`).
        solver: the solver (`brdffit.fitting.solvers.SOLVERS`): the engine's Levenberg-Marquardt.
        max_steps: the solver's step limit.
        rtol, atol: the solver's convergence tolerances (optimistix's Cauchy termination).
        seed: the seed of subsamples and quasi-random starts.
    """

    loss: str = "cosine"
    solver: str = "lm"
    max_steps: int = 256
    rtol: float = 1e-8
    atol: float = 1e-12
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class PosteriorDefaults:
    """A posterior's defaults (`brdffit.posterior`, docs/posterior.md).

    Attributes:
        walkers: emcee's walkers.
        steps: steps per walker in total (a stored chain is continued up to this many).
        seed: the seed of the walkers' start.
    """

    walkers: int = 32
    steps: int = 5000
    seed: int = 0


FIT = FitDefaults()
POSTERIOR = PosteriorDefaults()
