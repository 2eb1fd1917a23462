"""The fitting engine (docs/fitting.md), one concept per module:

- `problem`: what a fit solves (static structure, data arrays, residuals);
- `losses`: the registry of losses (residual, weighting, formula);
- `separable`: the linear amplitudes solved exactly (variable projection);
- `search`: the global start over the declared bounds of the nonlinear parameters;
- `solvers`: the solver table and the compiled, batched optimistix solve;
- `normal_equations`, `refine`: full-data sums in chunks and the refinement of large data;
- `uncertainty`: Laplace and sandwich standard errors;
- `status`: status, bounds, warnings, information criteria;
- `result`: `FitResult`, a value with its own storage;
- `api`: `fit` and `fit_many`, one pipeline; `progressive`: Lafortune lobes one after another.
"""

from .api import CHANNEL_MODES, FitError, fit, fit_many
from .progressive import fit_lobes
from .result import FitResult

__all__ = ["fit", "fit_many", "fit_lobes", "FitResult", "FitError", "CHANNEL_MODES"]
