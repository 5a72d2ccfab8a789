"""One shape per feature package: a newcomer finds the same role under the same file name in every package.

``run.py`` runs the feature and returns its result, ``cli.py`` is its ``aev-ocp`` command, ``plots.py`` draws it,
``outputs.py`` saves and loads what it writes (where it writes a folder of its own), ``section.py`` is its part
of ``aev-ocp reproduce`` (where it has one inside the package). The retired names (``api.py``, ``suite.py``,
``experiments.py``, ``output.py``, ``report_section.py``) must not come back beside them."""

from __future__ import annotations

from pathlib import Path

import pytest

PKG = Path(__file__).parents[2] / "aev_ocp"

#: each feature package and the roles it has (the shared ones are required of all)
SHAPE = {
    "mpc": {"run", "cli", "plots"},
    "ocp": {"run", "cli", "plots", "section"},
    "ring": {"run", "cli", "plots", "outputs"},
    "safety": {"run", "cli", "plots", "outputs", "section"},
    "stability": {"run", "cli", "plots", "outputs", "section"},
    "study": {"run", "cli"},
    "sumo": {"run", "cli", "plots", "outputs"},
}
RETIRED = ("api", "suite", "experiments", "output", "report_section")


@pytest.mark.parametrize("package", sorted(SHAPE))
def test_feature_package_has_its_roles_under_the_shared_names(package: str) -> None:
    have = {p.stem for p in (PKG / package).glob("*.py")}
    assert SHAPE[package] <= have, f"aev_ocp/{package} lacks {sorted(SHAPE[package] - have)}"
    assert {"run", "cli"} <= SHAPE[package]
    old = sorted(set(RETIRED) & have)
    assert not old, f"aev_ocp/{package} has retired role names {old}: use run/outputs/section"


def test_every_package_with_a_command_is_in_the_shape_table() -> None:
    with_cli = {p.parent.name for p in PKG.glob("*/cli.py")}
    assert with_cli - {"tuning"} == set(SHAPE), "a new feature package: add its roles to SHAPE"
