"""``aev-ocp stability --law NAME [--set carfollowing.NAME.param=value ...] [--speed-mps V ...] [--out DIR]``.

Linear string-stability analysis of a law at each equilibrium speed, measured attenuation of a
perturbation in a long platoon over a range of amplitudes, the linear prediction of the same
experiment; writes stability.json, gain.png, stable_region.png and attenuation.png. ``--law mpc``
measures the MPC platoon instead (closed loop, no linear analysis). Exit codes: 0 ok, 1 a measured
run stopped on an event (collision, negative speed; its numbers are still written), 2 bad input.

Options are SI (``--speed-mps``, ``--amplitude-mps``, ``--duration-s``, ``--omega-rad-per-s``), converted to
the laws' model units with ``--units-length-m`` L and ``--units-speed-mps`` U (time unit L/U); each has a
``*-model`` twin in model units, and giving both twins is an error naming both.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from ..limits import memory_limit_bytes
from ..params import ParameterError, Units

# the command line's one error format, exit codes and parser (aev_ocp/cli.py)
from ..console import EXIT_FAILED_RUN, EXIT_OK, bad_input
from ..console import OneLineParser as _Parser
from ..console import error_line as _err


_UNITS = Units()  # the paper's units (aev_ocp/params.py: L = 10 m, U = 5 m/s)
_V_STAR = 1.7  # default equilibrium speed [model speed]: the paper leader's v_l(20)
_OMEGA = 0.5 * math.pi  # default sinusoid frequency [rad/model time]: the paper leader's slow component sin(0.5πt)
_DURATION = 4.0  # default dip duration [model time]: the period of that component
_T = _UNITS.time_s

#: (SI option name, metavar, dest stem, SI help, model-unit help) of the options that have a *-model twin.
_TWINS = (
    (
        "speed-mps",
        "V",
        "speed",
        f"equilibrium speed v* [m/s] (repeatable; default {_V_STAR:g} model speed, the paper leader's v_l(20): "
        f"{_V_STAR * _UNITS.speed_mps:g} m/s at the default units)",
        "equilibrium speed v* in model speed instead (repeatable)",
    ),
    (
        "amplitude-mps",
        "A",
        "amplitude",
        "disturbance amplitude [m/s] (repeatable; default 1e-6 … Fig. 5's size, in model speed, below 0.95 v*)",
        "disturbance amplitude in model speed instead (repeatable)",
    ),
    (
        "omega-rad-per-s",
        "W",
        "omega",
        f"sinusoid frequency [rad/s] (default {_OMEGA:g} rad per model time: {_OMEGA / _T:g} rad/s at the default "
        "units)",
        "sinusoid frequency in rad per model time instead",
    ),
    (
        "duration-s",
        "D",
        "duration",
        f"dip duration [s] (default {_DURATION:g} model time: {_DURATION * _T:g} s at the default units)",
        "dip duration in model time instead",
    ),
)


def _model_values(a: argparse.Namespace, units: Units) -> dict[str, Any]:
    """speed, amplitude (lists or None), omega, duration in model units from the SI options or their *-model
    twins (argparse already refused both); ParameterError names the option of a bad value."""
    to_model = {
        "speed": units.speed_from_si,
        "amplitude": units.speed_from_si,
        "omega": lambda w: w * units.time_s,
        "duration": units.time_from_si,
    }
    out: dict[str, Any] = {}
    for name, _, dest, _, _ in _TWINS:
        si, model = getattr(a, f"{dest}_si"), getattr(a, f"{dest}_model")
        given, opt = (si, f"--{name}") if si is not None else (model, f"--{dest}-model")
        if given is None:
            out[dest] = None
            continue
        for x in given if isinstance(given, list) else [given]:
            if not (math.isfinite(x) and x > 0):
                raise ParameterError(f"{opt} {x!r}: must be a finite number > 0")
        conv = to_model[dest] if si is not None else (lambda x: x)
        out[dest] = [float(conv(x)) for x in given] if isinstance(given, list) else float(conv(given))
    return out


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp stability``."""
    p = _Parser(prog="aev-ocp stability", description=__doc__.splitlines()[0].rstrip(".").strip("`"))
    p.add_argument("--law", required=True, help="a registered law (ovm, ovfl, proposed, idm, ...) or 'mpc'")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="carfollowing.LAW.PARAM=VALUE",
        help="override a coefficient (also carfollowing.PARAM=VALUE for alpha, beta, kappa, eps)",
    )
    p.add_argument(
        "--units-length-m",
        type=float,
        default=_UNITS.length_m,
        metavar="L",
        help=f"length unit L [m] of the laws' model units, for converting the SI options and columns "
        f"(default {_UNITS.length_m:g}, the paper's)",
    )
    p.add_argument(
        "--units-speed-mps",
        type=float,
        default=_UNITS.speed_mps,
        metavar="U",
        help=f"speed unit U [m/s] (time unit L/U s; default {_UNITS.speed_mps:g}, the paper's)",
    )
    for name, metavar, dest, si_help, model_help in _TWINS:
        g = p.add_mutually_exclusive_group()
        action = "append" if dest in ("speed", "amplitude") else "store"
        g.add_argument(
            f"--{name}", dest=f"{dest}_si", action=action, type=float, default=None, metavar=metavar, help=si_help
        )
        g.add_argument(
            f"--{dest}-model",
            dest=f"{dest}_model",
            action=action,
            type=float,
            default=None,
            metavar=metavar.lower(),
            help=model_help,
        )
    p.add_argument(
        "--kind",
        choices=("pulse", "sine"),
        default="pulse",
        help="leader perturbation: a smooth speed dip (pulse) or a sinusoid (default pulse)",
    )
    p.add_argument("--followers", type=int, default=None, help="platoon size (default 50; 6 for --law mpc)")
    p.add_argument(
        "--predictor",
        default="constant-velocity",
        help="MPC leader forecast for --law mpc: constant-velocity, constant-acceleration, cooperative, oracle",
    )
    p.add_argument(
        "--ring",
        type=int,
        default=None,
        metavar="N",
        help="linear stability of uniform flow on a ring of N vehicles of this law instead (aev_ocp.ring)",
    )
    ring = p.add_mutually_exclusive_group()
    ring.add_argument("--spacing-m", type=float, default=None, help="--ring: spacing L/N front to front [m]")
    ring.add_argument("--density-per-km", type=float, default=None, help="--ring: vehicles per km")
    p.add_argument("--vehicle-length-m", type=float, default=5.0, help="--ring: vehicle length [m] (default 5)")
    p.add_argument(
        "--aev",
        default=None,
        metavar="LAW",
        help="--ring: a mixed ring: --aev-count vehicles of this law among the --law drivers (aev_ocp.stability.mixed)",
    )
    p.add_argument("--aev-count", type=int, default=None, help="--aev: automated vehicles, spread evenly (default 1)")
    p.add_argument(
        "--delay-s", type=float, default=None, help="--aev: reaction delay of the --law drivers [s] (default 0)"
    )
    p.add_argument("--linear-only", action="store_true", help="skip the simulations")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--out", default=None, help="output folder (default results/stability/<law>)")
    return p


def parse_sets(law_name: str, items: list[str]) -> tuple[dict[str, float], dict[str, float]]:
    """``carfollowing.LAW.PARAM=VALUE`` (for this law) and ``carfollowing.PARAM=VALUE`` (shared coefficients)."""
    own: dict[str, float] = {}
    shared: dict[str, float] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        parts = key.strip().split(".")
        if not sep or parts[0] != "carfollowing" or len(parts) not in (2, 3) or not all(parts):
            raise ParameterError(f"--set {item!r}: expected carfollowing.LAW.PARAM=VALUE or carfollowing.PARAM=VALUE")
        try:
            value = float(raw)
        except ValueError:
            raise ParameterError(f"--set {key}: value {raw!r} is not a number") from None
        if not math.isfinite(value):
            raise ParameterError(f"--set {key}: value {raw!r} is not finite")
        if len(parts) == 3:
            if parts[1].lower() != law_name.lower():
                raise ParameterError(f"--set {key}: names law {parts[1]!r}, but --law is {law_name!r}")
            own[parts[2]] = value
        else:
            shared[parts[1]] = value
    return own, shared


def build_law(name: str, sets: list[str], key: str = "--law") -> Any:
    """The law named ``name`` with the ``--set`` overrides applied; ParameterError names a bad field."""
    import dataclasses

    from ..models.carfollowing import LAW_REGISTRY, make_law
    from ..params import CarFollowingParams

    own, shared = parse_sets(name, sets)
    known = {f.name for f in dataclasses.fields(CarFollowingParams)} - {"model_units"}
    for k in shared:
        if k not in known:
            raise ParameterError(f"--set carfollowing.{k}: unknown coefficient: shared ones are {sorted(known)}")
    try:
        params = CarFollowingParams(**dict[str, Any](shared))
    except ParameterError as exc:
        raise ParameterError(f"--set carfollowing.*: {exc}") from None
    if name.lower() not in LAW_REGISTRY:
        alt = " or 'mpc'" if key == "--law" else ""
        raise ParameterError(f"{key} {name!r}: unknown law: known laws are {sorted(LAW_REGISTRY)}{alt}")
    try:
        law = make_law(name, params, **own)
    except ParameterError as exc:
        raise ParameterError(f"--set carfollowing.{name}.*: {exc}") from None
    except TypeError:
        factory = LAW_REGISTRY[name.lower()]
        fields: list[str] = [f.name for f in dataclasses.fields(factory)] if dataclasses.is_dataclass(factory) else []
        bad = [k for k in own if k not in fields]
        raise ParameterError(
            f"--set carfollowing.{name}.{bad[0] if bad else '?'}: unknown coefficient of law "
            f"{name!r}: known are {fields}"
        ) from None
    return law


#: Files ``aev-ocp stability`` writes (a foreign folder holding one of them is refused).
STABILITY_FILES = ("stability.json", "manifest.json", "gain.png", "attenuation.png", "stable_region.png")


def cli_stability(argv: list[str]) -> int:
    """Entry point of ``aev-ocp stability``; returns the exit code."""
    from ..mpc.settings import PREDICTOR_NAMES
    from ..results import OutputError, claim_output_dir
    from .run import run_stability

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    say = lambda m: print(f"[stability] {m}", file=sys.stderr, flush=True)  # noqa: E731
    try:
        memory_limit_bytes()  # a bad $AEV_OCP_MAX_MEMORY_GB is refused before anything else, as simulate and mpc do
        is_mpc = a.law.lower() == "mpc"
        if is_mpc and a.set:
            raise ParameterError("--set: the MPC has no car-following coefficients to set")
        if is_mpc and a.predictor not in PREDICTOR_NAMES:
            raise ParameterError(f"--predictor {a.predictor!r}: must be one of {PREDICTOR_NAMES}")
        for opt, val in (("--aev-count", a.aev_count), ("--delay-s", a.delay_s)):
            if val is not None and (a.aev is None or a.ring is None):  # silently ignored before
                raise ParameterError(f"{opt} {val!r}: only with --ring N --aev LAW (a mixed ring)")
        units = _units(a)
        law = None if is_mpc else build_law(a.law, a.set)
        if a.ring is not None:  # the ring's modes (aev_ocp.stability.ring)
            if law is None:
                raise ParameterError("--ring: needs a car-following law (--law), not the MPC")
            if a.aev is not None:
                return cli_mixed_ring_stability(
                    law,
                    build_law(a.aev, [], key="--aev"),
                    a.ring,
                    1 if a.aev_count is None else a.aev_count,
                    0.0 if a.delay_s is None else a.delay_s,
                    a.spacing_m,
                    a.density_per_km,
                    a.vehicle_length_m,
                    units,
                    Path(a.out) if a.out else Path("results") / "stability" / f"ring_{a.law.lower()}_{a.aev.lower()}",
                )
            return cli_ring_stability(
                law,
                a.ring,
                a.spacing_m,
                a.density_per_km,
                a.vehicle_length_m,
                units,
                Path(a.out) if a.out else Path("results") / "stability" / f"ring_{a.law.lower()}",
                not a.linear_only,
            )
        mv = _model_values(a, units)
        speeds = mv["speed"] or [_V_STAR]
        n = a.followers if a.followers is not None else (6 if is_mpc else 50)
        if n < 1 or n > 2000:
            raise ParameterError(f"--followers {n}: must be an integer in [1, 2000]")
        if is_mpc and a.linear_only:
            raise ParameterError("--linear-only: the MPC has no linear analysis here; drop the option")
        out = Path(a.out) if a.out else Path("results") / "stability" / a.law.lower()
        _check_speeds_and_amplitudes(a, law, speeds, mv["amplitude"], units)
        omega = mv["omega"] if mv["omega"] is not None else _OMEGA
        duration = mv["duration"] if mv["duration"] is not None else _DURATION
        if law is not None and not a.linear_only:  # the size of the measured runs, before the folder is claimed
            from .linear import analyse
            from .measure import check_measure_size

            check_measure_size([analyse(law, float(v)) for v in speeds], n, a.kind, omega, duration, "--followers")
        # before any work: a folder of another run or of the user's own files is refused
        claim_output_dir(out, "stability", a.law.lower(), None, STABILITY_FILES)
        doc = run_stability(
            law,
            speeds,
            out,
            amplitudes=mv["amplitude"],
            kind=a.kind,
            omega=omega,
            duration=duration,
            n_followers=n,
            measure_runs=not a.linear_only,
            mpc_predictor=a.predictor if is_mpc else None,
            plots=not a.no_plots,
            progress=say,
            units=units,
            size_key="--followers",
        )
    except (ParameterError, OutputError, OSError) as exc:
        return bad_input(exc)
    for line in summary_lines(doc):
        print(line)
    events = []
    for e in doc["speeds"]:
        for m in e["measured"]:
            if m["status"] != "ok":
                events.append(
                    f"v* = {e['v_star_mps']:.6g} m/s ({e['v_star_model']:g}), A = {m['amplitude_mps']:.6g} "
                    f"m/s ({m['amplitude_model']:g}): run stopped ({m['status']})"
                )
    print(f"wrote {len(doc.get('files', []))} files to {out}/")
    for e in events:
        _err(e)
    return EXIT_FAILED_RUN if events else EXIT_OK


def _check_speeds_and_amplitudes(
    a: argparse.Namespace, law: Any, speeds: list[float], amplitudes: list[float] | None, units: Units
) -> None:
    """Refuse, naming the option in its own units, a speed at which the law has no equilibrium gap and an
    amplitude above a speed (the leader would drive backwards)."""
    from .linear import equilibrium_gap_of

    sp, amp = ("--speed-mps", "--amplitude-mps")
    if a.speed_model is not None:
        sp = "--speed-model"
    if a.amplitude_model is not None:
        amp = "--amplitude-model"
    shown = lambda x: f"{units.speed_to_si(x):g} m/s ({x:g} model speed)"  # noqa: E731
    for v in speeds:
        if law is not None:
            try:
                equilibrium_gap_of(law, v)
            except ParameterError:
                raise ParameterError(
                    f"{sp}: law {law.name!r} has no equilibrium gap at v* = {shown(v)} "
                    "(f(h, v*, v*) does not change sign for h in [1e-4, 1e3] model length)"
                ) from None
        for x in amplitudes or []:
            if x > v:
                raise ParameterError(
                    f"{amp}: amplitude {shown(x)} is above v* = {shown(v)} (the leader would drive backwards)"
                )


def _units(a: argparse.Namespace) -> Units:
    """The [units] of --units-length-m and --units-speed-mps; ParameterError names the option."""
    for opt, x in (("--units-length-m", a.units_length_m), ("--units-speed-mps", a.units_speed_mps)):
        if not (math.isfinite(x) and x > 0):
            raise ParameterError(f"{opt} {x!r}: must be a finite number > 0")
    return Units(length_m=a.units_length_m, speed_mps=a.units_speed_mps)


def summary_lines(doc: dict[str, Any]) -> list[str]:
    """The lines ``aev-ocp stability`` prints for a stability.json document: SI first, the model value in
    parentheses (criterion C in 1/s², frequencies in rad/s)."""
    lines: list[str] = []
    for e in doc["speeds"]:
        head = f"v* = {e['v_star_mps']:.6g} m/s ({e['v_star_model']:g})"
        if "criterion_per_s2" in e:
            band, band_m = e["unstable_band_rad_per_s"], e["unstable_band_model"]
            lines.append(
                f"{head}: h* = {e['h_star_m']:.6g} m ({e['h_star_model']:.6g}), criterion C = "
                f"{e['criterion_per_s2']:.6g} 1/s² ({e['criterion_model']:.6g}), string stable: {e['string_stable']}, "
                f"platoon stable: {e['locally_stable']}, sup|G| = {e['max_gain']:.6g}"
                + (
                    f" at ω = {e['omega_max_gain_rad_per_s']:.4g} rad/s ({e['omega_max_gain_model']:.4g}), |G| > 1 "
                    f"for ω < {band[1]:.4g} rad/s ({band_m[1]:.4g})"
                    if band
                    else ""
                )
                + f", ℓ∞ gain ∫|g| = {e['peak_gain']:.6g}"
            )
        else:
            lines.append(f"{head}: {doc['law']['law']} (measured only)")
        if "linear_prediction" in e:
            lp = e["linear_prediction"]
            lines.append(
                f"  linear prediction: mean peak ratio {lp['ratio_peak']:.4f}, max ℓ2 step {lp['max_step_l2']:.4f}"
            )
        for m in e["measured"]:
            amp = f"{m['amplitude_mps']:.4g} m/s ({m['amplitude_model']:g})"
            lines.append(
                f"  A = {amp:<22} mean peak ratio {m['ratio_peak']:.4f}  max peak step "
                f"{m['max_step_peak']:.4f}  max ℓ2 step {m['max_step_l2']:.4f}  measured string stable: "
                f"{m['string_stable_measured']}"
                + (
                    ""
                    if m.get("agrees_with_linear") is None
                    else f"  linear: {'yes' if m['agrees_with_linear'] else 'no'}"
                )
                + f"  ({m['status']})"
            )
    return lines


#: Longest vehicle a ring may have [m]: 30 m is longer than any road vehicle (a 25.25 m EU road train).
MAX_VEHICLE_LENGTH_M = 30.0


def _ring_spacing_m(spacing_m: float | None, density_per_km: float | None, vehicle_length_m: float) -> float:
    """The front-to-front spacing [m] from --spacing-m or --density-per-km (one of them), checked."""
    if not (math.isfinite(vehicle_length_m) and 0 <= vehicle_length_m <= MAX_VEHICLE_LENGTH_M):
        raise ParameterError(
            f"--vehicle-length-m {vehicle_length_m!r}: must be a finite number of metres in [0, {MAX_VEHICLE_LENGTH_M:g}]"
        )
    if (spacing_m is None) == (density_per_km is None):
        raise ParameterError("--ring: give the spacing with --spacing-m or the density with --density-per-km (one)")
    if density_per_km is not None and not (math.isfinite(density_per_km) and density_per_km > 0):
        raise ParameterError(f"--density-per-km {density_per_km!r}: must be a finite number of vehicles per km > 0")
    spacing = spacing_m if spacing_m is not None else 1000.0 / float(density_per_km)  # type: ignore[arg-type]
    if not (math.isfinite(spacing) and spacing > vehicle_length_m):
        raise ParameterError(
            f"--spacing-m/--density-per-km: spacing {spacing:g} m must exceed the vehicle length "
            f"{vehicle_length_m:g} m (--vehicle-length-m)"
        )
    return spacing


def cli_mixed_ring_stability(
    human: Any,
    aev: Any,
    n: int,
    aev_count: int,
    delay_s: float,
    spacing_m: float | None,
    density_per_km: float | None,
    vehicle_length_m: float,
    units: Any,
    out: Path,
) -> int:
    """``aev-ocp stability --ring N --aev LAW``: the linear stability of a ring of N vehicles, ``aev_count`` of them
    (spread evenly) driven by ``aev`` and the rest by ``human`` with a reaction delay; the fewest such AEVs that
    stabilise it; writes mixed_ring_stability.json."""
    from ..results import claim_output_dir, write_json
    from .outputs import save_stability_manifest
    from .mixed import analyse_mixed_ring, even_placement, min_aev_count, si_accel

    spacing = _ring_spacing_m(spacing_m, density_per_km, vehicle_length_m)
    if not (2 <= n <= 2000):
        raise ParameterError(f"--ring {n} with --aev: must be an integer in [2, 2000] (a dense eigenproblem)")
    if not (0 <= aev_count <= n):
        raise ParameterError(f"--aev-count {aev_count}: must be an integer in [0, {n}] (the ring's vehicles)")
    if not (math.isfinite(delay_s) and 0 <= delay_s <= 5.0):
        raise ParameterError(f"--delay-s {delay_s!r}: must be a finite number of seconds in [0, 5]")
    claim_output_dir(
        out, "stability --ring --aev", f"{human.name}+{aev.name}", None, ["mixed_ring_stability.json", "manifest.json"]
    )
    h_fn, a_fn = si_accel(human, units), si_accel(aev, units)
    idx = set(even_placement(n, aev_count))
    accels = [a_fn if i in idx else h_fn for i in range(n)]
    delays = [0.0 if i in idx else delay_s for i in range(n)]
    v_max = 70.0  # m/s: above every road's limit; the equilibrium speed is found below it
    r = analyse_mixed_ring(accels, n * spacing, vehicle_length_m, v_max, delays_s=delays)
    m, growth = min_aev_count(h_fn, a_fn, n, n * spacing, vehicle_length_m, v_max, human_delay_s=delay_s)
    doc: dict[str, Any] = r.to_dict()
    doc.update(
        {
            "human_law": human.name,
            "aev_law": aev.name,
            "aev_positions": sorted(idx),
            "human_delay_s": delay_s,
            "spacing_m": spacing,
            "min_aev_count": m,
            "growth_by_aev_count_per_s": growth,
        }
    )
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "mixed_ring_stability.json", doc)
    save_stability_manifest(out, "mixed_ring_stability")  # aev_ocp.load(out) reads it back
    print(
        f"mixed ring of {n}: {aev_count} × {aev.name} among {human.name} (delay {delay_s:g} s), spacing {spacing:.6g} m: "
        f"equilibrium speed {r.v_star_mps:.6g} m/s"
    )
    print(
        f"  growth rate {r.growth_rate_per_s:.6g} 1/s (frequency {r.frequency_rad_per_s:.4g} rad/s); ring stable: "
        f"{r.ring_stable}; fewest evenly spread {aev.name} cars that stabilise it: "
        f"{m if m is not None else f'none of 0 … {n}'}"
    )
    print(f"wrote 2 files to {out}/")
    return EXIT_OK


def cli_ring_stability(
    law: Any,
    n: int,
    spacing_m: float | None,
    density_per_km: float | None,
    vehicle_length_m: float,
    units: Any,
    out: Path,
    measure: bool,
) -> int:
    """``aev-ocp stability --ring N``: the ring's modes, growth rate, wavelength, n → ∞ limit and the head-to-tail
    criterion, with the measured growth beside them; writes ring_stability.json."""
    from ..params import EVParams
    from ..results import claim_output_dir, write_json
    from .outputs import save_stability_manifest
    from .ring import measured_growth, ring_stability

    spacing = _ring_spacing_m(spacing_m, density_per_km, vehicle_length_m)
    if not (2 <= n <= 100_000):
        raise ParameterError(f"--ring {n}: must be an integer in [2, 100000]")
    claim_output_dir(
        out, "stability --ring", law.name, None, ["ring_stability.json", "manifest.json"]
    )  # before any work
    ev = EVParams(units=units)
    rs = ring_stability(law, n, n * spacing, vehicle_length_m, ev)
    doc: dict[str, Any] = rs.to_dict()
    if n > 200:
        doc["modes"] = doc["modes"][:100]  # thinned for the file
    meas = measured_growth(law, n, n * spacing, vehicle_length_m, ev) if measure and n <= 2000 else None
    doc["measured"] = meas
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "ring_stability.json", doc)
    save_stability_manifest(out, "ring_stability")  # aev_ocp.load(out) reads it back
    print(
        f"ring of {n} × {law.name} at spacing {spacing:.6g} m (gap {rs.gap_m:.6g} m, {1000 / spacing:.6g} veh/km): "
        f"uniform speed {rs.v_star_mps:.6g} m/s"
    )
    print(
        f"  growth rate {rs.growth_rate_per_s:.6g} 1/s (mode k = {rs.most_unstable_k}, wavelength "
        f"{rs.wavelength_m:.6g} m, wave speed {rs.wave_speed_mps:.4g} m/s); ring stable: {rs.ring_stable}"
    )
    print(
        f"  n → ∞: growth {rs.limit_growth_rate_per_s:.6g} 1/s at θ = {rs.limit_theta:.4g}; head-to-tail C = "
        f"{rs.criterion_per_s2:.6g} 1/s², string stable: {rs.string_stable}"
    )
    if meas is not None:
        print(
            f"  measured growth {meas['measured_per_s']:.6g} 1/s (predicted {meas['predicted_per_s']:.6g}, relative "
            f"error {meas['relative_error']:.2g}, run {meas['t_end_s']:.4g} s: {meas['status']})"
        )
    print(f"wrote 2 files to {out}/")
    return EXIT_OK
