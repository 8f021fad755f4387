"""Lazy public names: a package's names are imported from their modules when first used.

``import touchloc.belief`` then costs only what is used, not every estimator with numba,
trimesh and scipy behind it; ``from touchloc.belief import ScalingSeries`` imports
``touchloc.belief.scaling_series`` (and what it needs) at that moment. The public names
and their meaning are those of the eager imports they replace.
"""

from __future__ import annotations

import importlib
import os
import sys
import types

__all__ = ["attach"]


def attach(package: str, names: dict, *, fallback=None):
    """Make the public names of ``package`` import their module on first access.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : dict
        ``{submodule: (name, ...)}``: where each public name is defined (relative to the
        package).
    fallback : callable, optional
        ``fallback(name)`` for names not in ``names`` (e.g. deprecated aliases); it
        returns the value or raises AttributeError.

    Returns
    -------
    (__getattr__, __dir__)
        For the package's namespace (PEP 562).

    Notes
    -----
    A public name that is also a submodule's name (the function ``belief.identify`` in
    ``belief/identify.py``) must keep meaning the function after the submodule has been
    imported, although importing a submodule sets the package attribute of that name to
    the module. Those names become properties of the package's module class, which
    ignore that assignment.
    """
    where = {n: mod for mod, objs in names.items() for n in objs}
    pkg = sys.modules[package]
    here = os.path.dirname(pkg.__file__)
    shadowed = [n for n in where
                if os.path.exists(os.path.join(here, n + ".py")) or os.path.isdir(os.path.join(here, n))]

    def load(name):
        return getattr(importlib.import_module(f"{package}.{where[name]}"), name)

    def __getattr__(name):
        if name in where:
            value = load(name)
            setattr(pkg, name, value)  # later look-ups are plain attribute reads
            return value
        if name.startswith("__") or fallback is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return fallback(name)

    def __dir__():
        return sorted(set(vars(pkg)) | set(where))

    if shadowed:
        values = {}

        def prop(name):
            def get(self):
                if name not in values:
                    values[name] = load(name)
                return values[name]

            def put(self, value):
                if isinstance(value, types.ModuleType) and value.__name__ == f"{package}.{name}":
                    return  # the import system binding the submodule: the public name wins
                values[name] = value

            return property(get, put, doc=f"{package}.{name} (imported on first use)")

        pkg.__class__ = type("LazyPackage", (types.ModuleType,), {n: prop(n) for n in shadowed})
    return __getattr__, __dir__
