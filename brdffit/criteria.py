"""The criteria by which `brdffit.select` chooses a model, declared once (no JAX here: the CLI's choices come from
this module without loading the engine). docs/model-selection.md says when each one applies."""

from __future__ import annotations

__all__ = ["CRITERIA", "DEFAULT_MARGIN", "HELDOUT_MARGIN", "resolve_criterion"]

# "auto" is "bic" for measurements that state their uncertainty σ (a likelihood to score), else "heldout":
# measured files rarely state σ, and a misspecified model's information criterion then says little about how it
# predicts directions it was not fitted to.
CRITERIA = ("auto", "heldout", "aic", "bic", "cv")
# ΔAIC or ΔBIC within which a simpler model counts as good as the best (Kass & Raftery 1995: < 2 is "not worth
# more than a bare mention").
DEFAULT_MARGIN = 2.0
# The "heldout" criterion's margin: a simpler model whose error on the held-out directions is within this fraction
# of the best one's predicts as well; the held-out error of a few thousand rows is itself uncertain by a few per cent
# on peaked materials (docs/model-selection.md).
HELDOUT_MARGIN = 0.05


def resolve_criterion(criterion: str, measurements) -> str:
    """The criterion ``"auto"`` stands for: ``"bic"`` where the measurements state their uncertainty σ (the
    likelihood that an information criterion needs), else ``"heldout"``; any other criterion is itself.

    Raises:
        ValueError: a criterion not in `CRITERIA`.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    if criterion == "auto":
        return "bic" if measurements.sigma is not None else "heldout"
    return criterion
