"""``aev-ocp mpc-export``: the MPC step of a scenario as a self-contained C library (the C and its binding:
:mod:`aev_ocp.mpc.cstep`, whose names are re-exported here)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .cstep import (
    RECORD_FILE,
    COLD_MAX_ITER,
    COLD_REG0,
    COLD_REG_MAX,
    COLD_REG_STEP,
    EXPORT_FILES,
    LIBRARY_C,
    QP_MAX_ITER,
    QP_TOL,
    RTI_REG,
    STATUS,
    TEMPLATES,
    CompiledStep,
    CStep,
    ExportableController,
    ExportError,
    Info,
    build_library,
    check_exportable,
    config_header,
    export_controller,
    generate_casadi,
    qp_data_function,
    qp_dimension_defines,
    rti_functions,
    step_sources,
    write_sources,
)
from .controller import MPCController, resolve_formulation

__all__ = [
    "COLD_MAX_ITER",
    "COLD_REG0",
    "COLD_REG_MAX",
    "COLD_REG_STEP",
    "EXPORT_FILES",
    "LIBRARY_C",
    "QP_MAX_ITER",
    "QP_TOL",
    "RTI_REG",
    "STATUS",
    "TEMPLATES",
    "CompiledStep",
    "CStep",
    "ExportableController",
    "ExportError",
    "Info",
    "build_library",
    "check_exportable",
    "config_header",
    "export_controller",
    "generate_casadi",
    "qp_data_function",
    "qp_dimension_defines",
    "rti_functions",
    "step_sources",
    "write_sources",
    "export_controller_settings",
    "export_mpc",
    "build_parser",
    "cli_mpc_export",
]


def refuse_temperature_state(formulation: Any) -> None:
    """ExportError naming the key if the exported step cannot run ``formulation``: a pack-temperature state.
    Measured: on UDDS (120 s, limit 0.5 mK above ambient) the Riccati interior point failed 828 of 1360 QPs once
    the soft temperature limit was active, where HPIPM solved them all; the exported step has only the Riccati
    solver, so such a controller is refused rather than exported to fail in the car."""
    temperature = getattr(formulation, "temperature", None)
    if temperature is not None and temperature.temperature_state:
        raise ExportError(
            "[mpc] temperature_state = true: the exported step's QP solver (the Riccati interior point) does not "
            "solve the QPs of an active pack-temperature limit; export the MPC without the temperature state "
            "(in Python the controller then uses HPIPM)"
        )


def export_controller_settings(
    settings: Any,
    ev: Any = None,
    problem: Any = None,
    parameter_values: dict[str, float] | None = None,
    initial_values: dict[str, float] | None = None,
    formulation: Any = None,
) -> "MPCController":
    """A controller built only for the export (cold IPOPT path, no codegen: nothing is compiled; the IPOPT, which
    the export never runs, built only if the controller solves); a built-in
    formulation's problem is built as the rti path builds it (the OCV as comparisons, models/battery.py), and
    the controller keeps the formulation (its cold start: the exported step's COLD_ITER)."""
    from ..models.battery import piecewise_ocv
    from ..params import EVParams

    f = resolve_formulation(formulation, problem, parameter_values, initial_values)
    refuse_temperature_state(f)
    c: MPCController
    s = settings.with_(solver="ipopt-cold", codegen=False)
    if f.kind != "problem":
        with piecewise_ocv():
            c = MPCController(s, ev or EVParams(), formulation=f, export_only=True)
        return c
    return MPCController(s, ev, formulation=f, export_only=True)


#: Control steps of the recorded input an export writes (mpc_input.txt).
RECORD_STEPS = 200


def record_inputs(scenario: Any, c: Any, steps: int = RECORD_STEPS) -> np.ndarray:
    """(steps, 5 + 2N) inputs of the exported step in SI, one row per control step of dt·T seconds: x_meas
    (h [m], v [m/s], V1, V2 [V], S [-]) of the scenario's first follower driven by its closed-form law from the
    scenario's start (the plant of :func:`aev_ocp.simulate.simulate_platoon`), then the forecast: the leader's own
    speed [m/s] averaged over each interval of the horizon (Simpson's rule) and at each interval's start."""
    from ..simulate import simulate_platoon

    s, u = c.settings, scenario.ev.units
    N, dt = s.N, float(s.dt)
    kw = scenario.simulate_kwargs()
    r = simulate_platoon(
        scenario.leader,
        [scenario.laws[0]],
        kw["gaps0"][:1],
        kw["speeds0"][:1],
        steps * dt,
        ev=scenario.ev,
        dt_out=dt,
        rtol=kw["rtol"],
        atol=kw["atol"],
    )
    t = np.arange(steps) * dt
    idx = np.searchsorted(r.t, t - 1e-9 * dt)
    x = np.column_stack(
        [u.length_to_si(r.gap[idx, 0]), u.speed_to_si(r.speed[idx, 0]), r.V1[idx, 0], r.V2[idx, 0], r.S[idx, 0]]
    )
    vl = np.vectorize(lambda tt: float(scenario.leader.speed(tt)))
    k = np.arange(N) * dt
    a, m, b = t[:, None] + k, t[:, None] + k + 0.5 * dt, t[:, None] + k + dt
    v_hat = vl(a)
    v_mean = (v_hat + 4.0 * vl(m) + vl(b)) / 6.0
    return np.hstack([x, u.speed_to_si(v_mean), u.speed_to_si(v_hat)])


def export_mpc(scenario: Any, out: Path, settings: Any = None, formulation: Any = None) -> list[Path]:
    """Export the MPC of a loaded scenario (its ``[mpc]`` table; ExportError if it has none), with the recorded
    input of its benchmark (:func:`record_inputs`, mpc_input.txt)."""
    cfg = scenario.extra.get("mpc")
    if cfg is None:
        raise ExportError(f"scenario {scenario.name!r} has no [mpc] table: there is no MPC to export")
    s = settings or cfg.settings
    f = formulation or cfg.formulation
    c = export_controller_settings(s, scenario.ev, formulation=f)
    what = f"§9, objective {f.objective}" if f.kind == "s9" else f"the {f.name} formulation"
    desc = (
        f"MPC of scenario {scenario.name} (N = {s.N}, dt = {s.dt:g}, {what}, rk4_substeps {s.rk4_substeps}, "
        f"rti_iterations {s.rti_iterations}, Hessian {s.rti_hessian})"
    )
    files = export_controller(c, out, desc)
    rec = Path(out) / RECORD_FILE
    tmp = rec.with_name(f".{rec.name}.tmp")
    np.savetxt(tmp, record_inputs(scenario, c), fmt="%.17g")
    tmp.replace(rec)  # written whole or not at all
    return [*files, rec]


# ---------------------------------------------------------------------------------------------- command line
def build_parser() -> Any:
    """Argument parser of ``aev-ocp mpc-export``."""
    from ..console import OneLineParser

    p = OneLineParser(
        prog="aev-ocp mpc-export",
        description="Export the MPC step of a scenario's [mpc] table as a self-contained C library "
        "(sources, header mpc_step.h, Makefile, CMakeLists.txt, README.txt; no Python or "
        "CasADi at run time). The exported step is the real-time iteration with aev_ocp's "
        "Riccati interior-point QP solver (ocp_qp.c), whatever the scenario's solver.",
    )
    p.add_argument("scenario", help="scenario TOML file or shipped scenario name (e.g. mpc_paper_single)")
    p.add_argument("--out", required=True, help="output folder of the C sources (created; files replaced)")
    p.add_argument(
        "--set",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="override a scenario value, e.g. --set mpc.N=100 (repeatable)",
    )
    p.add_argument(
        "--build",
        action="store_true",
        help="also compile the library with the system C compiler ($CC, gcc or cc) into OUT/libaev_mpc.so",
    )
    return p


def cli_mpc_export(argv: list[str]) -> int:
    """Entry point of ``aev-ocp mpc-export``; exit 0 ok, 2 bad input (unknown scenario, no [mpc] table,
    no C compiler for --build), 1 a failed build."""
    from ..console import guarded

    return guarded(lambda: _cli(argv))


def _cli(argv: list[str]) -> int:
    from ..scenarios import load_with_sets
    from ..scenarios import find_scenario

    a = build_parser().parse_args(argv)
    sc = load_with_sets(str(find_scenario(a.scenario)), a.set)
    out = Path(a.out)
    if out.exists() and not out.is_dir():
        raise ExportError(f"--out {out} exists and is not a folder")
    _check_export(sc, out)
    files = export_mpc(sc, out)
    print(f"wrote {len(files)} files to {out}/ ({', '.join(f.name for f in files)})")
    if a.build:
        try:
            lib = build_library(out.resolve(), out.resolve() / "libaev_mpc.so")  # the compiler runs inside out
        except ExportError as exc:
            if "no C compiler" in str(exc):
                raise
            raise RuntimeError(str(exc)) from None
        print(f"built {lib}")
    return 0


def _check_export(sc: Any, out: Path) -> None:
    """Before any code is generated: the horizon within the memory budget (naming mpc.N), and ``out`` not a
    folder of another run or of the user's own files (aev_ocp.results.claim_output_dir)."""
    from ..limits import check_mpc_size
    from ..params import ParameterError
    from ..results import claim_output_dir

    cfg = sc.extra.get("mpc")
    if cfg is not None:
        refuse_temperature_state(cfg.formulation)
    N = int(cfg.settings.N) if cfg is not None else None
    if N is not None:
        try:
            check_mpc_size(N, 1, key="mpc.N")
        except ParameterError as exc:
            raise ParameterError(f"mpc-export: {exc}") from None
    claim_output_dir(
        out,
        "mpc-export",
        sc.name,
        str(sc.source) if sc.source else None,
        [*EXPORT_FILES, RECORD_FILE, "libaev_mpc.so"],
    )
