"""A failing report section or section provider fails ``reproduce`` with its error (issue 7 item 7):
before, a provider that raised on import was skipped and the run exited 0 without its section."""

from __future__ import annotations

import dataclasses
import io
import sys
import types

import pytest

from aev_ocp import reproduce as rp

# the built-in sections are not under test here: run none of them
NONE = dataclasses.replace(rp.ReproduceConfig.quick(), builtin=())


@pytest.fixture()
def clean_registry():
    saved = dict(rp._REGISTRY)
    rp._REGISTRY.clear()
    yield
    rp._REGISTRY.clear()
    rp._REGISTRY.update(saved)


def _boom(out_dir, progress):
    progress("about to fail")
    raise ValueError("the solver returned 7.25 where 3 was expected")


def test_a_section_that_raises_fails_reproduce_and_writes_no_report(tmp_path, clean_registry, monkeypatch) -> None:
    monkeypatch.setattr(rp, "load_providers", lambda providers, log=None: [])  # only the two sections below
    rp.register_section("ok-first", lambda d, p: "## fine\n")
    rp.register_section("broken", _boom)
    with pytest.raises(rp.ReportSectionError) as info:
        rp.reproduce(tmp_path, NONE, registered=True, stream=io.StringIO())
    msg = str(info.value)
    assert "'broken'" in msg and "ValueError" in msg and "7.25" in msg and "\n" not in msg
    assert not (tmp_path / "report.md").exists()


def test_a_provider_that_fails_to_import_fails_reproduce(monkeypatch) -> None:
    class Finder:  # a provider module whose import raises (e.g. a bug in the MPC package)
        def find_spec(self, name, path=None, target=None):  # noqa: ANN001
            if name != "aev_ocp_fake_provider":
                return None
            import importlib.machinery

            loader = types.SimpleNamespace(
                create_module=lambda spec: None,
                exec_module=lambda m: (_ for _ in ()).throw(NameError("name 'x' is not defined")),
            )
            return importlib.machinery.ModuleSpec(name, loader)

    monkeypatch.setattr(sys, "meta_path", [Finder(), *sys.meta_path])
    with pytest.raises(rp.ReportSectionError, match=r"aev_ocp_fake_provider failed to import: NameError"):
        rp.load_providers(("aev_ocp_fake_provider",))


def test_a_provider_with_a_missing_dependency_fails_but_an_absent_provider_is_skipped(monkeypatch) -> None:
    log: list[str] = []
    assert rp.load_providers(("aev_ocp.no_such_provider",), log=log.append) == []
    assert "not installed" in log[0]
    code = "import aev_ocp_dependency_that_does_not_exist\n"
    import importlib.abc
    import importlib.machinery

    class Loader(importlib.abc.Loader):
        def create_module(self, spec):  # noqa: ANN001
            return None

        def exec_module(self, module):  # noqa: ANN001
            exec(code, module.__dict__)

    class Finder:
        def find_spec(self, name, path=None, target=None):  # noqa: ANN001
            return importlib.machinery.ModuleSpec(name, Loader()) if name == "aev_ocp_fake_dep_provider" else None

    monkeypatch.setattr(sys, "meta_path", [Finder(), *sys.meta_path])
    with pytest.raises(rp.ReportSectionError, match="aev_ocp_dependency_that_does_not_exist"):
        rp.load_providers(("aev_ocp_fake_dep_provider",))
