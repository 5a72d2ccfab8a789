"""The [leader] table of a scenario file into a :class:`~aev_ocp.models.leader.LeaderProfile`: a constant speed,
the paper's leader, a drive cycle, arrays of times and speeds, or a recorded trace in a CSV file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ..models.leader import (
    CYCLES,
    LENGTH_UNITS,
    MAX_GAP_S,
    SPEED_UNITS,
    TIME_UNITS,
    ConstantSpeed,
    LeaderProfile,
    PaperLeader,
    SpeedTrace,
    drive_cycle,
    read_trace_csv,
    trace_leader,
)
from ..overrides import SI_TWINS
from ..params import ParameterError, Units
from .tables import ScenarioError, TableReader

LEADER_KINDS = ("constant", "paper", "cycle", "array", "trace")


def _trace(r: TableReader, units: Units, source: Path | None, t_max_s: float | None = None) -> LeaderProfile:
    """[leader] kind = "trace": a recorded trajectory in a CSV file, relative to the scenario file."""
    file = r.string("file")
    path = Path(file)
    if not path.is_absolute():
        path = (source.parent if source is not None else Path.cwd()) / path
    if not path.is_file():
        raise r.error(
            "file",
            file,
            f"not a regular file ({path}: a FIFO, device or folder)"
            if path.exists()
            else f"no such file ({path}); a relative path starts at the scenario file's folder",
        )
    speed, position = r.string("speed_column", None), r.string("position_column", None)
    if speed is not None and position is not None:
        raise r.error("position_column", position, "give speed_column or position_column, not both")
    if speed is None and position is None:
        speed = "speed"
    kw: dict[str, Any] = {
        "time_column": r.string("time_column", "time"),
        "speed_column": speed,
        "position_column": position,
        "time_unit": r.string("time_unit", "s", choices=tuple(TIME_UNITS)),
        "speed_unit": r.string("speed_unit", "m/s", choices=tuple(SPEED_UNITS)),
        "position_unit": r.string("position_unit", "m", choices=tuple(LENGTH_UNITS)),
        "max_gap_s": r.number("max_gap_s", MAX_GAP_S, gt=0),
    }
    if r.has("filter_column") != r.has("filter_value"):
        missing = "filter_value" if r.has("filter_column") else "filter_column"
        raise r.error(missing, None, "filter_column and filter_value go together (the rows of one vehicle)")
    if r.has("filter_column"):
        kw["filter_column"] = r.string("filter_column")
        value = r._get("filter_value", None)
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise r.error("filter_value", value, "expected a string or a number")
        kw["filter_value"] = value
    try:
        t, v = read_trace_csv(path, label=file, t_max_s=t_max_s, **kw)
    except ParameterError as exc:
        raise ScenarioError(f"{r.file}: {r.key_path('file')}: {exc}") from None
    return trace_leader(t, v, units, "trace")


#: MPCSettings' default horizon N and interval dt [model time] (aev_ocp/mpc/settings.py; tests/test_scenarios.py
#: holds them equal): the look-ahead a trace leader's file must cover, known here without importing the MPC.
MPC_DEFAULT_N, MPC_DEFAULT_DT = 25, 0.1


def trace_read_s(doc: dict[str, Any], t_end: float, units: Units) -> float:
    """How much of a trace leader's file a run reads [s]: twice (the horizon t_end [model time] + the MPC's look-ahead
    N·dt of the [mpc] table, at least MPCSettings' default): a 10^7-row recording is not read to its end for a
    2 s run, and an MPC forecast or a longer horizon set in Python still finds the recorded speeds."""
    mpc: dict[str, Any] = doc["mpc"] if isinstance(doc.get("mpc"), dict) else {}
    n, dt = mpc.get("N", MPC_DEFAULT_N), mpc.get("dt", MPC_DEFAULT_DT)
    ok = all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0 for x in (n, dt))
    look = max(float(n) * float(dt) if ok else 0.0, MPC_DEFAULT_N * MPC_DEFAULT_DT)
    return 2.0 * units.time_to_si(t_end + look)


def _leader(r: TableReader, units: Units, source: Path | None = None, t_max_s: float | None = None) -> LeaderProfile:
    kind = r.string("kind", choices=LEADER_KINDS)
    leader: LeaderProfile
    if kind == "trace":
        leader = _trace(r, units, source, t_max_s)
        r.finish()
        return leader
    try:
        if kind == "constant":
            leader = ConstantSpeed(r.quantity("v", units, ge=0))  # or v_mps [m/s]
        elif kind == "paper":
            d = PaperLeader()
            leader = PaperLeader(
                v0=r.quantity("v0", units, d.v0, ge=0),
                amplitude=r.quantity("amplitude", units, d.amplitude),
                t_end=r.quantity("forcing_end", units, d.t_end, gt=0),
            )
        elif kind == "cycle":
            leader = drive_cycle(r.string("cycle", choices=CYCLES), units)
        else:
            twins = [SI_TWINS["leader"][k][0] for k in ("times", "speeds") if r.has(SI_TWINS["leader"][k][0])]
            if twins and r.has("unit"):
                raise r.error(
                    "unit",
                    r.table["unit"],
                    f"applies to leader.times/leader.speeds; {twins[0]} is in SI "
                    "already: remove leader.unit or use the model keys",
                )
            unit = r.string("unit", "model", choices=("model", "si"))
            # unit = "si": times [s], speeds [m/s] (converted below); times_s / speeds_mps: converted here
            times = r.quantities("times", units, min_len=2)
            speeds = r.quantities("speeds", units, min_len=2, ge=0)
            if len(times) != len(speeds):
                raise r.error("speeds", speeds, f"needs one value per entry of leader.times ({len(times)})")
            if times[0] != 0 or any(b <= a for a, b in zip(times, times[1:])):
                raise r.error("times", times, "must start at 0 and increase strictly")
            leader = (
                SpeedTrace.from_si(times, speeds, units, label="array")
                if unit == "si"
                else SpeedTrace(tuple(times), tuple(speeds), label="array")
            )
    except ParameterError as exc:
        raise ScenarioError(f"{r.file}: {r.path}: {exc}") from None
    r.finish()
    return leader
