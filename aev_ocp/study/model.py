"""What a study is made of: its axes, controllers, points and tasks (frozen data; :class:`~aev_ocp.study.spec.Study`
holds them), and the error a study file raises."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


class StudyError(ValueError):
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
