"""Lazy package ``__init__``s: a package names what it exports, and each name is imported on first use.

Every package of ``aev_ocp`` states its public names as one table, ``_EXPORTS = {"Name": "submodule"}``
(a submodule of the package, or a whole dotted ``aev_ocp.…`` module for a name defined elsewhere), and hands it
to :func:`lazy_exports`::

    _EXPORTS = {"OCPProblem": "problem", "OCPResult": "aev_ocp.ocp_result"}
    __all__ = list(_EXPORTS)
    __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

so ``import aev_ocp.ocp.problem`` loads the problem description and nothing else the package exports. The layer
test (tests/test_layers.py) reads the same table as import edges, so a lazy name still counts where it points.
A name equal to its module's last part (``"battery": "battery"``) exports the submodule itself.
"""

from __future__ import annotations

import importlib
import sys
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
        if module.__name__.rsplit(".", 1)[-1] == name:
            value = module  # the export is the submodule itself (``from . import battery``)
        elif hasattr(module, name):
            value = getattr(module, name)
        else:
            raise AttributeError(f"module {package!r}: {name!r} is not defined in {module.__name__}")
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
