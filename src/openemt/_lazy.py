"""Packages whose public names are imported on first use (so that, e.g., ``openemt info``
reading a dataset does not load the figures, solvers and board libraries):
:func:`lazy_exports` gives such a package its ``__all__``, ``__getattr__`` and ``__dir__``."""

import importlib
import sys

__all__ = ["lazy_exports"]


def lazy_exports(package: str, sources: dict) -> tuple:
    """``(__all__, __getattr__, __dir__)`` of ``package``, whose public names live in the
    modules of ``sources`` (module name relative to ``package``, e.g. ``"._hdf5"`` -> the
    names it provides); a module is imported on the first use of one of its names, and the
    name is then kept in the package."""
    where = {name: module for module, names in sources.items() for name in names}
    names = sorted(where)

    def __getattr__(name):
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(names))

    return names, __getattr__, __dir__
