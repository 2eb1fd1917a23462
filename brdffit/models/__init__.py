"""The model library: lobes, their registry, and the composed `Model`.

`names()` lists the lobes; `get(spec, channels=3, **options_and_params)` builds a model from a spec string such as
``"lambert+cook-torrance"``.
"""

from .lobe import Lobe
from .model import Model, evaluate, evaluate_dirs
from .registry import describe, get, lobe_class, model_from_dict, model_to_dict, names, parse_spec

__all__ = ["Lobe", "Model", "names", "get", "lobe_class", "parse_spec", "describe", "evaluate", "evaluate_dirs",
           "model_to_dict", "model_from_dict"]
