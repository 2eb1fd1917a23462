"""The defaults of the options a user sets most, declared once.

`brdffit.fit`, `brdffit.fit_many`, `brdffit.select`, `brdffit.posterior`, the engine's solver and the readers of
tabulated files take their defaults from here, and the CLI its flags' defaults and help texts, so that a default changed here changes everywhere. No
JAX is imported: the CLI builds its parser from these without loading the engine.
"""

from __future__ import annotations

import dataclasses

__all__ = ["FIT", "POSTERIOR", "TABULATED", "FitDefaults", "PosteriorDefaults", "TabulatedDefaults"]


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


@dataclasses.dataclass(frozen=True)
class TabulatedDefaults:
    """How a tabulated file (MERL, RGL-EPFL) is read by default (`brdffit.io.tabulated`, docs/formats.md).

    Attributes:
        sampling: ``"directions"``: the file's interpolation at importance-weighted direction pairs (``"grid"``:
            its nodes).
        pairs: the direction pairs. With this many a selection screens its candidates on a subsample of 4,096
            training pairs (`brdffit.select.SCREEN_SAMPLES`) and measures their held-out error on 3,277 pairs; on
            the shared RGL-EPFL files the default fit then predicts held-out directions as well as or better than
            with half as many, at about the same time.
        max_theta_deg: the largest polar angle of the pairs, degrees.
    """

    sampling: str = "directions"
    pairs: int = 16384
    max_theta_deg: float = 80.0


FIT = FitDefaults()
POSTERIOR = PosteriorDefaults()
TABULATED = TabulatedDefaults()
