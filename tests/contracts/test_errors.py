"""Every exception class of aev_ocp derives from one base, aev_ocp.errors.AevOcpError (every warning category from
AevOcpWarning), and keeps the built-in base its callers catch (``except ValueError`` still works)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import warnings

import pytest

import aev_ocp
from aev_ocp.errors import AevOcpError, AevOcpWarning

#: Exceptions that must not be an Exception (so they pass ``except Exception``), with why.
NOT_EXCEPTIONS = {"aev_ocp.interrupts.Interrupted": "a KeyboardInterrupt: Ctrl-C and SIGTERM end the command"}

#: The built-in base each exception had before the common base came, which its callers may catch.
BUILTIN_BASES = {
    "aev_ocp.params.ParameterError": ValueError,
    "aev_ocp.scenarios.tables.ScenarioError": ValueError,
    "aev_ocp.saved.LoadError": ValueError,
    "aev_ocp.results.OutputError": ValueError,
    "aev_ocp.overrides.OverrideError": ValueError,
    "aev_ocp.study.model.StudyError": ValueError,
    "aev_ocp.report_sections.ReportSectionError": RuntimeError,
    "aev_ocp.report_html.ReportHTMLError": RuntimeError,
    "aev_ocp.study.runner.TimeLimitStop": RuntimeError,
    "aev_ocp.compiled.CompileWarning": RuntimeWarning,
    "aev_ocp.scenarios.tables.ScenarioWarning": UserWarning,
}


def package_exceptions() -> dict[str, type[BaseException]]:
    """{dotted name: class} of every exception class defined in a module of aev_ocp (each module imported)."""
    found: dict[str, type[BaseException]] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        modules = [aev_ocp] + [
            importlib.import_module(m.name) for m in pkgutil.walk_packages(aev_ocp.__path__, "aev_ocp.")
        ]
    for mod in modules:
        for _name, obj in inspect.getmembers(mod, inspect.isclass):
            if issubclass(obj, BaseException) and obj.__module__ == mod.__name__:
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def wrong_bases(classes: dict[str, type[BaseException]]) -> list[str]:
    """The classes that do not derive from their base, each with what it should derive from."""
    bad = []
    for name, cls in sorted(classes.items()):
        if cls in (AevOcpError, AevOcpWarning) or name in NOT_EXCEPTIONS:
            continue
        base = AevOcpWarning if issubclass(cls, Warning) else AevOcpError
        if not issubclass(cls, base):
            bad.append(f"{name} ({', '.join(b.__name__ for b in cls.__mro__[1:])}) must derive from {base.__name__}")
    return bad


def test_every_exception_class_derives_from_the_common_base() -> None:
    classes = package_exceptions()
    assert len(classes) >= 20, sorted(classes)  # the walk found the package's classes (21 when this was written)
    assert not wrong_bases(classes), "\n".join(wrong_bases(classes))
    for name in NOT_EXCEPTIONS:
        assert name in classes and not issubclass(classes[name], Exception), name


def test_a_class_without_the_base_is_named() -> None:
    """A planted exception class on ValueError alone is reported by name; one on the base is not."""

    class Planted(ValueError):
        pass

    class Kept(AevOcpError, ValueError):
        pass

    assert wrong_bases({"x.Planted": Planted, "x.Kept": Kept}) == [
        "x.Planted (ValueError, Exception, BaseException, object) must derive from AevOcpError"
    ]


@pytest.mark.parametrize("name, builtin", sorted(BUILTIN_BASES.items()))
def test_callers_that_catch_the_builtin_base_still_catch_it(name: str, builtin: type[BaseException]) -> None:
    cls = package_exceptions()[name]
    assert issubclass(cls, builtin)
    if not issubclass(cls, Warning):
        with pytest.raises(builtin, match="field x"):
            raise cls("field x: 3 is not allowed")


def test_the_base_is_exported_and_catches_a_real_refusal() -> None:
    """``except aev_ocp.AevOcpError`` catches what a bad parameter raises (EVParams with a negative mass)."""
    from aev_ocp.params import VehicleParams

    with pytest.raises(aev_ocp.AevOcpError, match="mass"):
        VehicleParams(mass_kg=-1.0)
