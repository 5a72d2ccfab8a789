"""Run ring and SUMO sweeps (:mod:`aev_ocp.study.traffic`'s tasks) through the study's executors into its store,
and table them: the driver above :mod:`aev_ocp.study.runner`, which itself runs one point through
:func:`aev_ocp.study.traffic.run_point` (so the tasks module stays below the runner)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..results import write_atomic, write_json
from .model import Task
from .runner import Store, execute
from .traffic import traffic_table


def run_traffic_study(
    tasks: list[Task],
    out: str | Path,
    *,
    executor: str = "pool",
    workers: int | None = None,
    scheduler: str | None = None,
    name: str = "traffic",
    time_limit_s: float | None = None,
    progress_stream: Any = None,
) -> tuple[dict[str, dict[str, Any]], list[dict[str, Any]]]:
    """Run the tasks through the study's executors into the store under ``out`` (resuming), table them, and write
    ``traffic.json`` and ``traffic.md`` there. Returns ({hash: result}, table rows)."""
    from ..ring.field import FIELD_METRICS, table_markdown

    outp = Path(out)
    store = Store(outp)
    results = execute(
        tasks,
        store,
        executor=executor,
        workers=workers,
        scheduler=scheduler,
        name=name,
        time_limit_s=time_limit_s,
        progress_stream=progress_stream,
    )
    rows = traffic_table(tasks, results)
    outp.mkdir(parents=True, exist_ok=True)
    write_json(outp / "traffic.json", {"study": name, "tasks": len(tasks), "rows": rows})
    metrics = [m for m in FIELD_METRICS if rows and m in rows[0]]
    write_atomic(outp / "traffic.md", (table_markdown(rows, metrics) if rows else "(no rows)") + "\n")
    return results, rows


__all__ = ["run_traffic_study"]
