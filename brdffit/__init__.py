"""brdffit: fit analytic BRDF models to measured reflectance.

Importing brdffit enables JAX's 64-bit mode (``jax_enable_x64``): fitted parameters, covariances and the
quadratures of `brdffit.properties` need double precision. Arrays passed in as float32 stay float32.
"""

import jax

jax.config.update("jax_enable_x64", True)

from . import geometry, models, params  # noqa: E402
from .models import Model, evaluate, evaluate_dirs  # noqa: E402
from .params import ParamSpec  # noqa: E402

__version__ = "0.1.0"

__all__ = ["Model", "ParamSpec", "evaluate", "evaluate_dirs", "geometry", "models", "params", "__version__"]
