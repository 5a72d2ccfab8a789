"""What a study is made of: its axes, controllers, points and tasks (frozen data; :class:`~aev_ocp.study.spec.Study`
holds them), and the error a study file raises."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..errors import AevOcpError


#: The study table's fixed columns (:mod:`aev_ocp.study.table`): % change against the reference of CHANGE_METRICS, and
#: the equal-distance and equal-time views: pack ∫Q per km of every run of a point up to the
#: shortest common distance / the common time of that point's runs, and its rank (1 = lowest).
CHANGE_METRICS = ("omega_model", "heat_pack_J", "heat_pack_J_per_km")
EQUAL_VIEWS = (("eq_distance", "distance", "cut_m"), ("eq_time", "time", "cut_s"))
EQUAL_METRIC = "heat_pack_J_per_km"
TABLE_LEAD = ("study", "point", "scenario")
TABLE_AFTER = (
    (
        "controller",
        "vehicle",
        "status",
        "message",
        "comparable",
        "flag_distance",
        "flag_duration",
        "flag_event",
        "distance_diff_pct",
        "duration_diff_pct",
    )
    + tuple(f"{m}_change_pct" for m in CHANGE_METRICS)
    + tuple(
        c
        for p, _, cut in EQUAL_VIEWS
        for c in (f"{p}_{cut}", f"{p}_{EQUAL_METRIC}", f"{p}_rank", f"{p}_{EQUAL_METRIC}_change_pct")
    )
)
TABLE_TAIL = ("wall_s", "task_hash", "aev_ocp_version", "casadi_version", "git_commit")
#: columns build_rows adds beside the metrics: the vehicle's own status and the OCP-D rows' bound check
TABLE_EXTRA = ("vehicle_status", "ocpd_role", "ocpd_role_reason")


class StudyError(AevOcpError, ValueError):
    """A study file is invalid; the message names the study file, the axis and the key."""


@dataclass(frozen=True)
class Axis:
    """One axis: keys (dotted scenario paths) and rows of values (one value per key per row)."""

    keys: tuple[str, ...]
    rows: tuple[tuple[Any, ...], ...]
    kind: str  # "grid" | "zip" | "random"
    seed: int | None = None

    @property
    def label(self) -> str:
        """The axis as messages name it."""
        return ", ".join(self.keys)


@dataclass(frozen=True)
class Controller:
    """A controller to compare: kind 'law' (name = law), 'mpc' (settings = [mpc] keys) or 'ocpd'."""

    label: str
    kind: str
    name: str = ""
    settings: tuple[tuple[str, Any], ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready description (part of every task's hash)."""
        return {"label": self.label, "kind": self.kind, "name": self.name, "settings": dict(self.settings)}


@dataclass(frozen=True)
class Point:
    """One point of the study: index, base scenario name, axis values {key: value}, the overridden document."""

    index: int
    base: str
    values: dict[str, Any]
    document: dict[str, Any]
    file: str


@dataclass(frozen=True)
class Task:
    """A point run by one controller: the unit of work (picklable, hash-keyed)."""

    point: int
    controller: str
    spec: dict[str, Any]
    key: str
