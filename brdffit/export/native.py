"""brdffit's own JSON description of a model or a fit, which `brdffit.models.model_from_dict` reads back."""

from __future__ import annotations

import json
import math

import numpy as np

__all__ = ["write"]


def _json_value(value):
    value = np.asarray(value, dtype=float)
    if value.ndim == 0:
        return float(value) if math.isfinite(float(value)) else None
    return [float(v) if math.isfinite(v) else None for v in value.tolist()]


def write(model, result, generator: str) -> str:
    """The JSON text.

    Arguments:
        model: the `Model`, or None for a fit in ``channel_mode="independent"`` (one model per channel).
        result: the `FitResult` or None; adds ``"stderr"`` and ``"status"``.
        generator: ``"brdffit <version>"``.

    Returns:
        ``{"comment", "generator", "spec", "channels", "params"}`` (or ``"channel_mode"`` and ``"models"``), plus
        the fit's ``"stderr"`` and ``"status"``.
    """
    from ..models import model_to_dict

    if model is None:
        out = {"comment": f"{generator} export of model {result.spec} (one model per channel)",
               "generator": generator, "channel_mode": result.channel_mode,
               "models": [model_to_dict(m) for m in result.models]}
    else:
        out = {"comment": f"{generator} export of model {model.spec}", "generator": generator}
        out.update(model_to_dict(model))
    if result is not None:
        out["stderr"] = {k: _json_value(v) for k, v in result.stderr.items()}
        out["status"] = result.status
    return json.dumps(out, indent=2) + "\n"
