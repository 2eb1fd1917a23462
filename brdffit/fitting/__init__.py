"""The fitting engine (docs/fitting.md), one concept per module:

- `problem`: what a fit solves (static structure, data arrays, residuals);
- `losses`: the registry of losses (residual, weighting, formula);
- `separable`: the linear amplitudes solved exactly (variable projection);
- `search`: the global start over the declared bounds of the nonlinear parameters;
- `solvers`: the solver table and the compiled, batched optimistix solve;
- `marquardt`: the default solver, Levenberg-Marquardt stepped on the host over compiled passes (polish and
  full-data refinement);
- `normal_equations`: the passes: JᵀJ, Jᵀr and the cost of a batch of points, in chunks;
- `uncertainty`: Laplace and sandwich standard errors;
- `status`: status, bounds, warnings, information criteria;
- `result`: `FitResult`, a value with its own storage;
- `api`: `fit` and `fit_many`, one pipeline; `progressive`: Lafortune lobes one after another.

The public names are imported on first use (`brdffit._lazy`).
"""

from .._lazy import exports as _exports

_PUBLIC = {"fit": "api:fit", "fit_many": "api:fit_many", "fit_lobes": "progressive:fit_lobes",
           "FitResult": "result:FitResult", "FitError": "api:FitError", "CHANNEL_MODES": "api:CHANNEL_MODES"}
_exports(__name__, _PUBLIC)

__all__ = sorted(_PUBLIC)
