"""``aev-ocp stability --law NAME [--set carfollowing.NAME.param=value ...] [--speed V ...] [--out DIR]``.

Linear string-stability analysis of a law at each equilibrium speed, measured attenuation of a
perturbation in a long platoon over a range of amplitudes, the linear prediction of the same
experiment; writes stability.json, gain.png, stable_region.png and attenuation.png. ``--law mpc``
measures the MPC platoon instead (closed loop, no linear analysis). Exit codes: 0 ok, 1 a measured
run stopped on an event (collision, negative speed; its numbers are still written), 2 bad input.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from ..params import ParameterError

# the command line's one error format, exit codes and parser (aev_ocp/cli.py)
from ..cli import EXIT_BAD_INPUT, EXIT_FAILED_RUN, EXIT_OK
from ..cli import OneLineParser as _Parser
from ..cli import error_line as _err


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``aev-ocp stability``."""
    p = _Parser(prog="aev-ocp stability", description=__doc__.splitlines()[0].strip("`"))
    p.add_argument("--law", required=True, help="a registered law (ovm, ovfl, proposed, idm, ...) or 'mpc'")
    p.add_argument("--set", action="append", default=[], metavar="carfollowing.LAW.PARAM=VALUE",
                   help="override a coefficient (also carfollowing.PARAM=VALUE for alpha, beta, kappa, eps)")
    p.add_argument("--speed", action="append", type=float, default=None, metavar="V",
                   help="equilibrium speed v* [model speed] (repeatable; default 1.7, the paper's v_l(20))")
    p.add_argument("--amplitude", action="append", type=float, default=None, metavar="A",
                   help="disturbance amplitude [model speed] (repeatable; default 1e-6 … Fig. 5's size)")
    p.add_argument("--kind", choices=("pulse", "sine"), default="pulse",
                   help="leader perturbation: a smooth speed dip (pulse) or a sinusoid (default pulse)")
    p.add_argument("--omega", type=float, default=0.5 * math.pi, help="sinusoid frequency [rad/model time]")
    p.add_argument("--duration", type=float, default=4.0, help="dip duration [model time] (default 4)")
    p.add_argument("--followers", type=int, default=None, help="platoon size (default 50; 6 for --law mpc)")
    p.add_argument("--predictor", default="constant-velocity",
                   help="MPC leader forecast for --law mpc: constant-velocity, constant-acceleration, "
                        "cooperative, oracle")
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


def build_law(name: str, sets: list[str]) -> Any:
    """The law named ``name`` with the ``--set`` overrides applied; ParameterError names a bad field."""
    import dataclasses

    from ..models.carfollowing import LAW_REGISTRY, make_law
    from ..params import CarFollowingParams

    own, shared = parse_sets(name, sets)
    known = {f.name for f in dataclasses.fields(CarFollowingParams)}
    for k in shared:
        if k not in known:
            raise ParameterError(f"--set carfollowing.{k}: unknown coefficient: shared ones are {sorted(known)}")
    try:
        params = CarFollowingParams(**shared)
    except ParameterError as exc:
        raise ParameterError(f"--set carfollowing.*: {exc}") from None
    if name.lower() not in LAW_REGISTRY:
        raise ParameterError(f"--law {name!r}: unknown law: known laws are {sorted(LAW_REGISTRY)} or 'mpc'")
    try:
        law = make_law(name, params, **own)
    except ParameterError as exc:
        raise ParameterError(f"--set carfollowing.{name}.*: {exc}") from None
    except TypeError:
        factory = LAW_REGISTRY[name.lower()]
        fields: list[str] = [f.name for f in dataclasses.fields(factory)] if dataclasses.is_dataclass(factory) else []
        bad = [k for k in own if k not in fields]
        raise ParameterError(f"--set carfollowing.{name}.{bad[0] if bad else '?'}: unknown coefficient of law "
                             f"{name!r}: known are {fields}") from None
    return law


def cli_stability(argv: list[str]) -> int:
    """Entry point of ``aev-ocp stability``; returns the exit code."""
    from ..mpc.settings import PREDICTOR_NAMES
    from .api import run_stability

    try:
        a = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    say = lambda m: print(f"[stability] {m}", file=sys.stderr, flush=True)  # noqa: E731
    try:
        is_mpc = a.law.lower() == "mpc"
        if is_mpc and a.set:
            raise ParameterError("--set: the MPC has no car-following coefficients to set")
        if is_mpc and a.predictor not in PREDICTOR_NAMES:
            raise ParameterError(f"--predictor {a.predictor!r}: must be one of {PREDICTOR_NAMES}")
        law = None if is_mpc else build_law(a.law, a.set)
        speeds = a.speed or [1.7]
        for v in speeds:
            if not (math.isfinite(v) and v > 0):
                raise ParameterError(f"--speed {v!r}: must be a finite number > 0")
        n = a.followers if a.followers is not None else (6 if is_mpc else 50)
        if n < 1 or n > 2000:
            raise ParameterError(f"--followers {n}: must be an integer in [1, 2000]")
        for nm, val in (("--omega", a.omega), ("--duration", a.duration)):
            if not (math.isfinite(val) and val > 0):
                raise ParameterError(f"{nm} {val!r}: must be a finite number > 0")
        if is_mpc and a.linear_only:
            raise ParameterError("--linear-only: the MPC has no linear analysis here; drop the option")
        out = Path(a.out) if a.out else Path("results") / "stability" / a.law.lower()
        doc = run_stability(law, speeds, out, amplitudes=a.amplitude, kind=a.kind, omega=a.omega,
                            duration=a.duration, n_followers=n, measure_runs=not a.linear_only,
                            mpc_predictor=a.predictor if is_mpc else None, plots=not a.no_plots, progress=say)
    except ParameterError as exc:
        _err(str(exc))
        return EXIT_BAD_INPUT
    except OSError as exc:
        _err(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))
        return EXIT_BAD_INPUT
    events = []
    for e in doc["speeds"]:
        head = f"v* = {e['v_star']:g}"
        if "criterion" in e:
            band = e["unstable_band"]
            print(f"{head}: h* = {e['h_star']:.6g}, criterion C = {e['criterion']:.6g}, string stable: "
                  f"{e['string_stable']}, platoon stable: {e['locally_stable']}, sup|G| = {e['max_gain']:.6g}"
                  + (f" at ω = {e['omega_max_gain']:.4g}, |G| > 1 for ω < {band[1]:.4g}" if band else "")
                  + f", ℓ∞ gain ∫|g| = {e['peak_gain']:.6g}")
        if "linear_prediction" in e:
            lp = e["linear_prediction"]
            print(f"  linear prediction: mean peak ratio {lp['ratio_peak']:.4f}, max ℓ2 step {lp['max_step_l2']:.4f}")
        for m in e["measured"]:
            print(f"  A = {m['amplitude']:<8g} mean peak ratio {m['ratio_peak']:.4f}  max peak step "
                  f"{m['max_step_peak']:.4f}  max ℓ2 step {m['max_step_l2']:.4f}  measured string stable: "
                  f"{m['string_stable_measured']}"
                  + ("" if m.get("agrees_with_linear") is None else
                     f"  linear: {'yes' if m['agrees_with_linear'] else 'no'}") + f"  ({m['status']})")
            if m["status"] != "ok":
                events.append(f"{head}, A = {m['amplitude']:g}: run stopped ({m['status']})")
    print(f"wrote {len(doc.get('files', []))} files to {out}/")
    for e in events:
        _err(e)
    return EXIT_FAILED_RUN if events else EXIT_OK
