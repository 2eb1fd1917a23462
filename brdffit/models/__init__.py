"""The model library: lobes, their registry, and the composed `Model`.

`names()` lists the lobes; `get(spec, channels=3, **options_and_params)` builds a model from a spec string such as
``"lambert+cook-torrance"``.

The names load on first use (`brdffit._lazy`): the registry and the lobes' declarations without JAX, `Model`
and the evaluations with it.
"""

from .._lazy import exports as _exports

_PUBLIC = {"Lobe": "lobe:Lobe", "Model": "model:Model", "evaluate": "model:evaluate",
           "evaluate_dirs": "model:evaluate_dirs", **{name: f"registry:{name}" for name in (
               "names", "get", "lobe_class", "parse_spec", "describe", "model_to_dict", "model_from_dict")}}
_exports(__name__, _PUBLIC)

__all__ = sorted(_PUBLIC)
