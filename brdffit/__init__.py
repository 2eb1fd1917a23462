"""brdffit: fit analytic BRDF models to measured reflectance.

Importing brdffit enables JAX's 64-bit mode (``jax_enable_x64``): fitted parameters, covariances and the
quadratures of `brdffit.properties` need double precision; fits run in float64.

Public API:

- models: `models.names`, `models.get`, `Model`, `evaluate`, `evaluate_dirs`, `ParamSpec`;
- data: `Measurements`, `MeasurementError`, `io.load`, `io.save`, `synth.generate`;
- fitting: `fit`, `fit_many`, `FitResult`, `FitError`;
- uncertainty: `posterior`, `Posterior`;
- model selection: `select`, `Selection`, `fit_lobes`, `Scene` (and `scene.interpolate`, `scene.scene_error`);
- physical checks: `properties`;
- previews and renderer export: `render`, `export`.
"""

import jax

jax.config.update("jax_enable_x64", True)

from . import geometry, io, models, params, properties, render, scene, synth  # noqa: E402
from .fitting import FitError, FitResult, fit, fit_lobes, fit_many  # noqa: E402
from .measurements import MeasurementError, Measurements  # noqa: E402
from .posterior import Posterior, posterior  # noqa: E402
from .scene import Scene  # noqa: E402
from .select import Selection, select  # noqa: E402
from .models import Model, evaluate, evaluate_dirs  # noqa: E402
from .params import ParamSpec  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "Model", "ParamSpec", "evaluate", "evaluate_dirs", "Measurements", "MeasurementError", "fit", "fit_many",
    "FitResult", "FitError", "posterior", "Posterior", "select", "Selection", "fit_lobes", "Scene",
    "geometry", "io", "models", "params", "properties", "render", "scene", "synth", "__version__",
]
