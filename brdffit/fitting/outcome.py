"""How a fit ended: `Status`, declared once with its order of severity (docs/fitting.md explains each), and what
one start's solve ended with: `SolveOutcome`.

A status is a `str` (an `enum.StrEnum`): it compares equal to its name, is written as its name to JSON, HDF5 and
tables, and is read back by ``Status(name)``. No JAX is imported: the CLI reads statuses from batch tables.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterable
from typing import Any

__all__ = ["Status", "STATUSES", "SolveOutcome"]


class Status(enum.StrEnum):
    """How a fit ended, from the best to the worst (the declaration order is the severity).

    - ``converged``: the solver's termination test passed and a further Gauss-Newton step predicts no decrease;
    - ``converged-at-bound``: the same, with parameters on a bound (named in ``bounds_hit``); at a bound the
      Karush-Kuhn-Tucker condition is what is tested: the descent direction points out of the box;
    - ``stalled``: the solver stopped where a Gauss-Newton step still predicts a decrease above
      `brdffit.fitting.status.STALL_TOLERANCE` of the cost (undamped Gauss-Newton thrown far away, a bound
      transform saturated on the way);
    - ``max-steps``: the step limit was reached first;
    - ``nonfinite``: the cost is not finite.
    """

    CONVERGED = "converged"
    CONVERGED_AT_BOUND = "converged-at-bound"
    STALLED = "stalled"
    MAX_STEPS = "max-steps"
    NONFINITE = "nonfinite"

    @property
    def converged(self) -> bool:
        """Whether the fit's answer is an optimum (inside the box or on its boundary)."""
        return self in (Status.CONVERGED, Status.CONVERGED_AT_BOUND)

    @property
    def unfinished(self) -> bool:
        """Whether a solve stopped short of an optimum with a finite cost (stalled or at its step limit): the case
        that the pipeline's hold rounds and pruning resume."""
        return self in (Status.STALLED, Status.MAX_STEPS)

    @property
    def severity(self) -> int:
        """0 for ``converged`` up to 4 for ``nonfinite``."""
        return _ORDER.index(self)

    @classmethod
    def worst(cls, statuses: Iterable) -> "Status":
        """The most severe of ``statuses`` (names or members), e.g. of a fit's independent channels."""
        return max((cls(s) for s in statuses), key=lambda s: s.severity)


_ORDER = tuple(Status)
STATUSES = tuple(s.value for s in Status)


@dataclasses.dataclass(frozen=True)
class SolveOutcome:
    """What the solve of one start ended with: `brdffit.fitting.marquardt.solve`, the compiled optimistix solve
    or, with nothing nonlinear free, the projection alone; the pipeline's later stages (revive, hold, prune,
    refine) give new outcomes built from it with `dataclasses.replace`.

    Attributes:
        params: physical values of every parameter.
        cost: Σr² at ``params``.
        steps: the solver's steps, summed over the stages that led here.
        max_steps: the step limit was reached first.
        nonfinite: the cost is not finite.
        normal: the normal equations of the solver's last pass (the default solver; None from the others).
        exact: ``normal`` is the pass at ``params`` itself.
        answer: the solver marked this start as its material's answer.
        notes: what the pipeline did on the way (a lobe searched again, parameters held, a lobe pruned), in
            words; they open the result's warnings.
        pruned: the amplitudes pruning held at 0.
    """

    params: dict
    cost: float
    steps: int = 0
    max_steps: bool = False
    nonfinite: bool = False
    normal: Any = None
    exact: bool = False
    answer: bool = False
    notes: tuple[str, ...] = ()
    pruned: tuple[str, ...] = ()

    @property
    def status(self) -> Status:
        """The solver's own verdict (``nonfinite``, ``max-steps`` or ``converged``), before the diagnosis of the
        answer (`brdffit.fitting.status.diagnose`) refines it."""
        if self.nonfinite:
            return Status.NONFINITE
        return Status.MAX_STEPS if self.max_steps else Status.CONVERGED
