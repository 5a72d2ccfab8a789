"""Scenario files: a TOML file a user edits, validated into a frozen :class:`Scenario`.

Every field is checked. An unknown key, a wrong type or a value out of range raises
:class:`ScenarioError` (a ValueError) whose message names the file, the key path (e.g.
``vehicle.mass_kg``), the value and what is allowed. Parameter dataclasses keep their own checks:
a :class:`~aev_ocp.params.ParameterError` is caught and re-raised with the file and key path.

Schema (model units unless a key says otherwise; see README.md "Scenario files")::

    name = "table1"                     # optional, defaults to the file stem
    description = "..."                 # optional
    compare = ["proposed", "ovfl"]      # optional: run the whole platoon once per law

    [units]       length_m, speed_mps                       (model guide §1)
    [leader]      kind = "constant" | "paper" | "cycle" | "array"
                  constant: v                               [model speed]
                  paper:    v0, amplitude, forcing_end      (paper eq. acc5; forcing_end [model time])
                  cycle:    cycle = "udds" | "hwfet" | "us06" (SI data, converted with [units])
                  array:    times, speeds, unit = "model" | "si"  (si: [s], [m/s])
                  trace:    file (CSV, relative to the scenario file), time_column ("time"),
                            speed_column ("speed") | position_column, time_unit ("s" | "ms" | "min"),
                            speed_unit ("m/s" | "km/h" | "mph" | "ft/s"), position_unit ("m" | "km" |
                            "ft" | "mi"), max_gap_s (10), filter_column + filter_value (one vehicle's rows);
                            resampled as the cycles are (linear, held after the end)
    [platoon]     followers, law | laws, gap0_first, gap0_others | gap0 | gaps0,
                  speed0 | speed0_factor | speeds0
    [carfollowing] alpha, beta, kappa, eps; a sub-table per law name holds that law's
                  coefficients, e.g. [carfollowing.idm] a_max = 1.0
    [simulation]  t_end [model time], dt_out, rtol, atol

Every model-unit key has an SI twin (:data:`SI_TWINS`), converted with the file's ``[units]``:
simulation.t_end_s, dt_out_s [s]; platoon.gap0_m, gap0_first_m, gap0_others_m, gaps0_m [m],
speed0_mps, speeds0_mps [m/s]; leader.v_mps, v0_mps [m/s], amplitude_mps2 [m/s²], forcing_end_s,
times_s [s], speeds_mps [m/s]. Give one key of a pair, not both.

    [vehicle] [cell] [pack]  fields of VehicleParams, CellParams, PackParams (SI names); [cell] name = "<shipped
                  cell>" (aev_ocp/data/cells/, e.g. "a123_anr26650") or file = "<cell file>" selects a cell file
                  (aev_ocp.cells), its other keys override it; the pack layout stays in [pack]
    [thermal]     fields of ThermalParams: enabled, ambient_K, T0_K, h_Wpm2K, cooling_power_W, T_max_K (the lumped
                  pack temperature, aev_ocp.models.thermal; off by default)
    [limits]      fields of VehicleLimits (SI names): a_min_mps2, a_max_mps2, jerk_max_mps3, lag_s,
                  v_max_mps, enabled; every vehicle's physical limits, enforced by the plant for every
                  controller (default: VehicleLimits(); the paper's scenarios state enabled = false)

Other top-level tables are rejected unless a module registered them with
:func:`register_section`; their validated values land in ``Scenario.extra``.

One module per job; every name is importable from ``aev_ocp.scenarios``: :mod:`.tables` (a table's typed getters
and the errors), :mod:`.sections` (the registry of top-level tables), :mod:`.vehicle` ([units] ... [thermal]),
:mod:`.leader` (the leader), :mod:`.followers` ([carfollowing], [platoon]), :mod:`.size` (the memory budget),
:mod:`.platoon` (:class:`Scenario` and :func:`parse_scenario`), :mod:`.shipped` (finding files), :mod:`.files`
(reading a file, :func:`load_scenario`).
"""

from __future__ import annotations

from ..limits import DEFAULT_MEMORY_LIMIT_GB as DEFAULT_MEMORY_LIMIT_GB  # re-exported: the budget lives in limits
from ..limits import estimate_run_bytes as estimate_run_bytes
from ..limits import memory_limit_bytes as memory_limit_bytes
from ..overrides import SI_TWINS as SI_TWINS
from ..overrides import si_twin as si_twin
from .files import MAX_FILE_BYTES, load_scenario, load_with_sets, read_scenario_doc, read_scenario_text
from .followers import _carfollowing, _platoon
from .leader import LEADER_KINDS, _leader, _trace
from .platoon import Scenario, apply_to_scenario, check_leader_speed, parse_scenario
from .sections import SECTION_PROVIDERS, STANDALONE_SECTIONS, SectionValidator, register_section, registered_sections
from .shipped import (
    PACKAGED_DIR_NAME,
    SCENARIO_DIR_NAME,
    find_scenario,
    iter_shipped,
    packaged_scenario_dir,
    scenario_dirs,
    shipped_scenarios,
)
from .size import MAX_SAMPLES, MIN_SAMPLES, check_run_size, thinned_dt_out
from .tables import ScenarioError, ScenarioWarning, TableReader, _params, read_declared
from .vehicle import read_ev, standalone_header

__all__ = [
    "DEFAULT_MEMORY_LIMIT_GB",
    "LEADER_KINDS",
    "MAX_FILE_BYTES",
    "MAX_SAMPLES",
    "MIN_SAMPLES",
    "PACKAGED_DIR_NAME",
    "SCENARIO_DIR_NAME",
    "SECTION_PROVIDERS",
    "SI_TWINS",
    "STANDALONE_SECTIONS",
    "Scenario",
    "ScenarioError",
    "ScenarioWarning",
    "SectionValidator",
    "TableReader",
    "apply_to_scenario",
    "check_leader_speed",
    "check_run_size",
    "estimate_run_bytes",
    "find_scenario",
    "iter_shipped",
    "load_scenario",
    "load_with_sets",
    "memory_limit_bytes",
    "packaged_scenario_dir",
    "parse_scenario",
    "read_declared",
    "read_ev",
    "read_scenario_doc",
    "read_scenario_text",
    "register_section",
    "registered_sections",
    "scenario_dirs",
    "shipped_scenarios",
    "si_twin",
    "standalone_header",
    "thinned_dt_out",
]
__all__ += ["_carfollowing", "_leader", "_params", "_platoon", "_trace"]  # used by the other scenario forms
