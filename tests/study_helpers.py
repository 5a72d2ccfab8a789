"""The tiny study the tests of several subjects run (output folders, the pool, overrides, reports, CLI errors, the
study's files): Table 1 cut to 2 followers and 1.5 model time, two points, two laws; written by
:func:`write_tiny_study`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

TINY_STUDY = """
name = "{name}"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.t_end" = 1.5
"simulation.dt_out" = 0.05
"platoon.followers" = 2
[[axes]]
key = "platoon.gap0_first"
values = [0.35, 0.9]
[controllers]
laws = ["proposed", "ovfl"]
"""
TINY_AXIS = 'key = "platoon.gap0_first"\nvalues = [0.35, 0.9]'  # the template's axis, for a test to replace


def write_tiny_study(tmp_path: Path, name: str = "tiny", text: str = TINY_STUDY) -> Path:
    """``text`` (default the tiny study) named ``name`` written to ``tmp_path/<name>.toml``; the file's path."""
    f = tmp_path / f"{name.replace('/', '_')}.toml"
    f.write_text(text.replace("{name}", name))
    return f


def record_cluster_stops(monkeypatch: Any) -> list[bool]:
    """A list that receives ``graceful`` of every :meth:`LocalClusterProcess.stop` call from now on (the stops still
    happen)."""
    from aev_ocp.study.cluster import LocalClusterProcess

    stops: list[bool] = []
    real_stop = LocalClusterProcess.stop

    def stop(self: LocalClusterProcess, *args: Any, **kwargs: Any) -> None:
        stops.append(kwargs.get("graceful", True))
        real_stop(self, *args, **kwargs)

    monkeypatch.setattr(LocalClusterProcess, "stop", stop)
    return stops
