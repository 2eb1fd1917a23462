"""Lazy imports, so that ``brdffit --help``, ``brdffit info`` and ``import brdffit`` do not pay for JAX, SciPy and
optimistix before something uses them (importing those takes far longer than the CLI's light commands' own work).

`exports` makes each public name of a package load from its submodule on first access (PEP 562's module
``__getattr__``, through the package's module class). `module` is a stand-in for a module that is imported on first
attribute access (for registries whose declarations are light but whose functions use JAX).
"""

from __future__ import annotations

import importlib
import sys
import types

__all__ = ["exports", "module"]


def exports(package: str, names: dict) -> None:
    """Make the public ``names`` of ``package`` (an imported package's ``__name__``) load on first access.

    Arguments:
        package: the package's name.
        names: public name -> ``"submodule"`` (the submodule itself) or ``"submodule:attribute"``, relative to
            the package. An attribute named like its own submodule (`brdffit.select`, the function in
            ``select.py``) stays the attribute: importing the submodule later does not replace it, as it did
            not when the package imported its names eagerly.
    """
    shadowed = {name for name, target in names.items() if target.partition(":")[0] == name and ":" in target}

    class Package(types.ModuleType):
        def __getattr__(self, name):
            try:
                target = names[name]
            except KeyError:
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
            where, _, attribute = target.partition(":")
            value = importlib.import_module(f"{package}.{where}")
            value = getattr(value, attribute) if attribute else value
            types.ModuleType.__setattr__(self, name, value)
            return value

        def __setattr__(self, name, value):
            # The import system binds a submodule on its package once it is loaded; keep the public attribute.
            if name in shadowed and isinstance(value, types.ModuleType):
                return
            types.ModuleType.__setattr__(self, name, value)

        def __dir__(self):
            return sorted(set(names) | set(self.__dict__))

    sys.modules[package].__class__ = Package


class module(types.ModuleType):
    """A module imported on first attribute access: ``jnp = module("jax.numpy")``."""

    def __init__(self, name: str):
        super().__init__(name)
        self.__dict__["_loaded"] = None

    def __getattr__(self, attribute):
        if self.__dict__["_loaded"] is None:
            self.__dict__["_loaded"] = importlib.import_module(self.__name__)
        return getattr(self.__dict__["_loaded"], attribute)
