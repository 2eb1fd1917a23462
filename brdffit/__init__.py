"""brdffit: fit analytic BRDF models to measured reflectance.

Importing brdffit enables JAX's 64-bit mode (``jax_enable_x64``): fitted parameters, covariances and the
quadratures of `brdffit.properties` need double precision; fits run in float64. The public names below are
imported on first use (`brdffit._lazy`), so that the command line's light commands never load JAX.

Public API:

- models: `models.names`, `models.get`, `Model`, `evaluate`, `evaluate_dirs`, `ParamSpec`;
- data: `Measurements`, `MeasurementError`, `io.load`, `io.save`, `synth.generate`;
- fitting: `fit`, `fit_many`, `FitResult`, `FitError`;
- databases on a Dask cluster: `fit_database` (`brdffit.distributed`);
- uncertainty: `posterior`, `Posterior`;
- model selection: `select`, `Selection`, `fit_lobes`, `Scene` (and `scene.scene_error`, `interpolation.interpolate`);
- physical checks: `properties`;
- previews and renderer export: `render`, `export`.
"""

import os as _os
import sys as _sys

from ._lazy import exports as _exports
from ._memory import cap_malloc_arenas as _cap_malloc_arenas

_cap_malloc_arenas()  # under `ulimit -v`, before JAX starts its threads (brdffit._memory)

# 64-bit JAX: through the environment when JAX is not imported yet (it reads JAX_ENABLE_X64 on import), else at
# once.
if "jax" in _sys.modules:
    _sys.modules["jax"].config.update("jax_enable_x64", True)
else:
    _os.environ["JAX_ENABLE_X64"] = "True"

__version__ = "0.1.0"

_PUBLIC = {
    "geometry": "geometry", "io": "io", "models": "models", "params": "params", "properties": "properties",
    "plausibility": "plausibility", "render": "render", "scene": "scene", "interpolation": "interpolation",
    "synth": "synth", "export": "export",
    "FitError": "fitting:FitError", "FitResult": "fitting:FitResult", "fit": "fitting:fit",
    "fit_lobes": "fitting:fit_lobes", "fit_many": "fitting:fit_many", "fit_database": "distributed:fit_database",
    "MeasurementError": "measurements:MeasurementError", "Measurements": "measurements:Measurements",
    "Posterior": "posterior:Posterior", "posterior": "posterior:posterior", "Scene": "scene:Scene",
    "Selection": "select:Selection", "select": "select:select", "Model": "models:Model",
    "evaluate": "models:evaluate", "evaluate_dirs": "models:evaluate_dirs", "ParamSpec": "params:ParamSpec",
}
_exports(__name__, _PUBLIC)

__all__ = sorted(_PUBLIC) + ["__version__"]
