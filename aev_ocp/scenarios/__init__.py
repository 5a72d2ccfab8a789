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

from ..lazy import lazy_exports

#: name -> module that defines it (imported on first use: aev_ocp.lazy)
_EXPORTS = {
    "DEFAULT_MEMORY_LIMIT_GB": "aev_ocp.limits",
    "estimate_run_bytes": "aev_ocp.limits",
    "memory_limit_bytes": "aev_ocp.limits",
    "SI_TWINS": "aev_ocp.overrides",
    "si_twin": "aev_ocp.overrides",
    "MAX_FILE_BYTES": "files",
    "load_scenario": "files",
    "load_with_sets": "files",
    "read_scenario_doc": "files",
    "read_scenario_text": "files",
    "_carfollowing": "followers",
    "_platoon": "followers",
    "LEADER_KINDS": "leader",
    "_leader": "leader",
    "_trace": "leader",
    "Scenario": "platoon",
    "apply_to_scenario": "platoon",
    "check_leader_speed": "platoon",
    "parse_scenario": "platoon",
    "SECTION_PROVIDERS": "providers",
    "STANDALONE_SECTIONS": "sections",
    "SectionValidator": "sections",
    "register_section": "sections",
    "registered_sections": "sections",
    "PACKAGED_DIR_NAME": "shipped",
    "SCENARIO_DIR_NAME": "shipped",
    "find_scenario": "shipped",
    "iter_shipped": "shipped",
    "packaged_scenario_dir": "shipped",
    "scenario_dirs": "shipped",
    "shipped_scenarios": "shipped",
    "MAX_SAMPLES": "size",
    "MIN_SAMPLES": "size",
    "check_run_size": "size",
    "thinned_dt_out": "size",
    "ScenarioError": "tables",
    "ScenarioWarning": "tables",
    "TableReader": "tables",
    "_params": "tables",
    "read_declared": "tables",
    "read_ev": "vehicle",
    "standalone_header": "vehicle",
}

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

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
