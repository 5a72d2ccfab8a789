"""Top-level entry points of the OCP package (Python API behind ``aev-ocp ocp …``)."""

from __future__ import annotations

from .prop31 import run_prop31

__all__ = ["run_prop31"]
