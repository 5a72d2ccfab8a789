"""Lazy package ``__init__``s: a package names what it exports, and each name is imported on first use.

Every package of ``aev_ocp`` states its public names as one table, ``_EXPORTS = {"Name": "submodule"}``
(a submodule of the package, or a whole dotted ``aev_ocp.…`` module for a name defined elsewhere), and hands it
to :func:`lazy_exports`::

    _EXPORTS = {"OCPProblem": "problem", "OCPResult": "aev_ocp.ocp_result"}
    __all__ = list(_EXPORTS)
    __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

so ``import aev_ocp.ocp.problem`` loads the problem description and nothing else the package exports. The layer
test (tests/contracts/test_layers.py) reads the same table as import edges, so a lazy name still counts where it points.
A name equal to its module's last part (``"battery": "battery"``) exports the submodule itself, unless the submodule
defines that name (``"measure": "measure"``: the function), which then stays the package's ``measure`` even after
the submodule is imported, as an eager ``from .measure import measure`` kept it.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any, Callable


def target_module(package: str, where: str) -> str:
    """The dotted module an ``_EXPORTS`` value names: ``where`` itself when it starts with ``aev_ocp.``, else
    the submodule ``package.where`` (a leading dot is allowed)."""
    return where if where.split(".", 1)[0] == "aev_ocp" else f"{package}.{where.lstrip('.')}"


def lazy_exports(package: str, exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for the package ``package`` (its ``__name__``) whose names ``exports`` maps to
    the module that defines each; a name is imported on first use and then kept in the package's namespace."""

    def __getattr__(name: str) -> Any:
        where = exports.get(name)
        if where is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = importlib.import_module(target_module(package, where))
        if hasattr(module, name):
            value = getattr(module, name)
        elif module.__name__ == f"{package}.{name}":
            value = module  # the export is the submodule itself (``from . import battery``)
        else:
            raise AttributeError(f"module {package!r}: {name!r} is not defined in {module.__name__}")
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    shadowing = {n for n, where in exports.items() if target_module(package, where) == f"{package}.{n}"}
    if shadowing:  # e.g. the function ``measure`` of the submodule ``measure``
        sys.modules[package].__class__ = _shadowing_package(shadowing)
    return __getattr__, __dir__


def _shadowing_package(names: set[str]) -> type[types.ModuleType]:
    """A module class that keeps ``pkg.name`` the export ``name`` of the submodule ``pkg.name`` (a function named as
    its module), as an eager ``from .name import name`` did: the import system sets ``pkg.name`` to the submodule
    whenever that is imported, and this puts the submodule's own ``name`` there instead."""

    class ShadowingPackage(types.ModuleType):
        def __setattr__(self, name: str, value: Any) -> None:
            if (
                name in names
                and isinstance(value, types.ModuleType)
                and value.__name__ == f"{self.__name__}.{name}"
                and hasattr(value, name)
            ):
                value = getattr(value, name)
            super().__setattr__(name, value)

    return ShadowingPackage
