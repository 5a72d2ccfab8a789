"""Mutation check (GitHub issue 15): plant semantic bugs one at a time and see whether the suite fails.

For every mutation in :data:`MUTATIONS` the tracked files of the repository (``git ls-files``, plus
untracked files that git does not ignore, so uncommitted tests take part) are copied to a temporary
folder, ONE textual replacement is applied there (the worktree is never touched), and the test
suite is run in the copy with ``python -m pytest -x -q -n 2 -p no:cacheprovider``.

To keep the whole run short, each mutation first runs its own module's test files (``Mutation.tests``;
the fast exact-check files of :data:`FAST_FILES` for the mutations before issue 41; single process,
``-x``); only a mutation that survives them runs the whole suite. A mutation is *caught* (killed)
when either run fails; the first failing test and its message (the margin: how far the checked
number moved) are recorded. Each mutation names its bug class (:data:`KINDS`: a sign, a sample
shift, a missing term, a swapped order, a wrong norm, a wrong limit); the run ends with
killed/survived per class.

Run from the repository root:

    python benchmarks/mutation.py                 # all mutations
    python benchmarks/mutation.py --only M1 M7    # a subset
    python benchmarks/mutation.py --full          # skip the fast stage: whole suite for every mutation
    python benchmarks/mutation.py --list          # the mutations, no run
    python benchmarks/mutation.py --own --only M38 M39   # only their own test files (minutes, not the suite)
    python benchmarks/mutation.py --kind "wrong norm"    # one bug class

Prints a table (mutation, class, file, killed?, first failing test, seconds) and writes
``benchmarks/mutation.json`` (``--json`` to change). Not part of the test suite. About 15–30 min
on 2 quiet cores when every mutation is caught by the fast stage.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FAST_FILES = ("tests/contracts/test_independent.py", "tests/test_models.py")
PYTEST = (sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider")


@dataclass(frozen=True)
class Mutation:
    """Replace ``old`` (must occur exactly once in ``path``) by ``new``. ``kind``: the bug class (one of
    :data:`KINDS`); ``tests``: the module's own test files, run as the fast stage instead of :data:`FAST_FILES`
    (issue 41: each module's own tests must catch a bug of each class)."""

    key: str
    what: str
    path: str
    old: str
    new: str
    kind: str = "other"
    tests: tuple[str, ...] = ()


#: bug classes of issue 41 (the ones before it are 'other')
KINDS = ("sign", "sample shift", "missing term", "swapped order", "wrong norm", "wrong limit", "other")


MUTATIONS: tuple[Mutation, ...] = (
    # the eight of issue 15, at their current locations
    Mutation(
        "M1",
        "stage cost uses w_V where w_r belongs",
        "aev_ocp/ocp/following.py",
        "pb.add_stage_cost(wk * terms[nm], nm)",
        'pb.add_stage_cost((wt[1] if nm == "relative" else wk) * terms[nm], nm)',
    ),
    Mutation(
        "M2",
        "eta and 1/eta swapped in the exact powertrain switch",
        "aev_ocp/models/powertrain.py",
        "ca.if_else(P_w > 0, P_w / p.efficiency, p.efficiency * P_w)",
        "ca.if_else(P_w > 0, p.efficiency * P_w, P_w / p.efficiency)",
    ),
    Mutation(
        "M3",
        "factor 2 dropped from the current root",
        "aev_ocp/models/powertrain.py",
        "return 2.0 * P_c / (E + ca.sqrt(",
        "return 1.0 * P_c / (E + ca.sqrt(",
    ),
    Mutation(
        "M4",
        "R2 in the V1 branch of the cell",
        "aev_ocp/models/battery.py",
        "-V1 / (p.R1_ohm * p.C1_F)",
        "-V1 / (p.R2_ohm * p.C1_F)",
    ),
    Mutation(
        "M5",
        "kappa v^2 -> kappa v in the proposed law",
        "aev_ocp/models/carfollowing.py",
        "return -kappa * v**2 * dv2",
        "return -kappa * v * dv2",
    ),
    Mutation(
        "M6",
        "OMEGA_A / OMEGA_B swapped in the compiled omega",
        "aev_ocp/simulate.py",
        "#define OMEGA_A {0.5 * (1 / eta + eta)!r}\\n#define OMEGA_B {0.5 * (1 / eta - eta)!r}",
        "#define OMEGA_A {0.5 * (1 / eta - eta)!r}\\n#define OMEGA_B {0.5 * (1 / eta + eta)!r}",
    ),
    Mutation(
        "M7",
        "RK4 weights (1,2,2,1)/6 -> (1,1,1,1)/4",
        "aev_ocp/numerics.py",
        "x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)",
        "x = x + dt / 4 * (k1 + k2 + k3 + k4)",
    ),
    Mutation(
        "M8",
        "time unit T = U/L instead of L/U in the following ODE",
        "aev_ocp/models/ego.py",
        "T = ev.units.time_s",
        "T = ev.units.speed_mps / ev.units.length_m",
    ),
    # more of the same kind
    Mutation(
        "M9",
        "R1 <-> R2 in Q_irr",
        "aev_ocp/models/battery.py",
        "V1**2 / p.R1_ohm + V2**2 / p.R2_ohm",
        "V1**2 / p.R2_ohm + V2**2 / p.R1_ohm",
    ),
    Mutation(
        "M10",
        "sign of the beta term (OVFL)",
        "aev_ocp/models/carfollowing.py",
        "+ beta * (v_l - v) / h**2",
        "+ beta * (v - v_l) / h**2",
    ),
    Mutation(
        "M11",
        "epsilon placement (eps v^2 in the denominator)",
        "aev_ocp/models/carfollowing.py",
        "dv2 / (dv2 + eps)",
        "dv2 / (dv2 + eps * v**2)",
    ),
    Mutation(
        "M12", "C1 in place of C2 in the V2 branch", "aev_ocp/models/battery.py", "+ I / p.C2_F,", "+ I / p.C1_F,"
    ),
    Mutation(
        "M13",
        "Q_irr missing the V2 term",
        "aev_ocp/models/battery.py",
        "p.R_s_ohm * I**2 + V1**2 / p.R1_ohm + V2**2 / p.R2_ohm",
        "p.R_s_ohm * I**2 + V1**2 / p.R1_ohm",
    ),
    Mutation(
        "M14",
        "OCV evaluated at 1 - S in the current map",
        "aev_ocp/models/powertrain.py",
        "E = battery.ocv(S, p.cell) - V1 - V2",
        "E = battery.ocv(1 - S, p.cell) - V1 - V2",
    ),
    Mutation(
        "M15",
        "soft-constraint penalty sign",
        "aev_ocp/ocp/problem.py",
        "self.add_stage_cost(soft * sigma +",
        "self.add_stage_cost(-soft * sigma +",
    ),
    Mutation(
        "M16",
        "plant event rule offset sign (negative speed)",
        "aev_ocp/plant.py",
        '"v", 1.0, -PLAN_TOLERANCE, False',
        '"v", 1.0, PLAN_TOLERANCE, False',
    ),
    Mutation(
        "M17",
        "smoothed eta switch: sigma on the wrong branch",
        "aev_ocp/models/powertrain.py",
        "P_w * (sigma / p.efficiency + (1 - sigma) * p.efficiency)",
        "P_w * ((1 - sigma) / p.efficiency + sigma * p.efficiency)",
    ),
    Mutation(
        "M18",
        "eta and 1/eta swapped in g (plant omega, energy objective)",
        "aev_ocp/models/energy.py",
        "ca.if_else(u >= 0, u / eta, eta * u)",
        "ca.if_else(u >= 0, eta * u, u / eta)",
    ),
    Mutation(
        "M19",
        "SOC rate in minutes (360 for 3600)",
        "aev_ocp/models/battery.py",
        "-I / (3600.0 * p.capacity_Ah)",
        "-I / (360.0 * p.capacity_Ah)",
    ),
    Mutation(
        "M20",
        "RK4 quadrature weights (1,2,2,1) -> (1,1,1,1) (Lagrange cost)",
        "aev_ocp/numerics.py",
        "q = q + dt / 6 * (g(x) + 2 * g(x + dt / 2 * k1) + 2 * g(x + dt / 2 * k2) + g(x + dt * k3))",
        "q = q + dt / 4 * (g(x) + g(x + dt / 2 * k1) + g(x + dt / 2 * k2) + g(x + dt * k3))",
    ),
    Mutation(
        "M21",
        "sign of V2 in Q",
        "aev_ocp/models/battery.py",
        "return I * (V1 + V2) + p.R_s_ohm * I**2",
        "return I * (V1 - V2) + p.R_s_ohm * I**2",
    ),
    Mutation(
        "M22",
        "cell power divided by N_s only",
        "aev_ocp/models/powertrain.py",
        "return P_b / pack.n_cells",
        "return P_b / pack.n_series",
    ),
    Mutation(
        "M23",
        "w_r term uses the interval-mean leader speed",
        "aev_ocp/ocp/following.py",
        "terms = following_stage_terms(z, a, v_hat,",
        "terms = following_stage_terms(z, a, v_mean,",
    ),
    Mutation(
        "M24",
        "gap dynamics use v_hat instead of the interval mean",
        "aev_ocp/ocp/following.py",
        "rhs = following_ode(z, a, v_mean, ev, smooth, Tst)",
        "rhs = following_ode(z, a, v_hat, ev, smooth, Tst)",
    ),
    Mutation(
        "M25",
        "plant's pack heat quadrature not scaled by T",
        "aev_ocp/plant.py",
        'quad += [T * b["Q_pack"], T * b["Q_irr_pack"]]',
        'quad += [b["Q_pack"], T * b["Q_irr_pack"]]',
    ),
    Mutation(
        "M26",
        "cascade's Q and Q_irr quadratures swapped",
        "aev_ocp/simulate.py",
        'quad += [T * b["Q_pack"], T * b["Q_irr_pack"]]',
        'quad += [T * b["Q_irr_pack"], T * b["Q_pack"]]',
    ),
    Mutation(
        "M27",
        "acceleration unit U/L instead of U^2/L",
        "aev_ocp/params.py",
        "return self.speed_mps**2 / self.length_m",
        "return self.speed_mps / self.length_m",
    ),
    Mutation(
        "M28",
        "OCP-D solves with the default weights, not the scenario's",
        "aev_ocp/ocp/oracle.py",
        'return scn.formulation.parameter_vector(list(pr.meta.get("parameter_names", [])))',
        'return scn.formulation.parameter_vector(list(pr.meta.get("parameter_names", [])), FollowingWeights())',
    ),
    Mutation(
        "M29",
        "MPC ignores the per-solve weights",
        "aev_ocp/mpc/controller.py",
        "wt = weight_vector(weights or self.formulation.weights)",
        "wt = weight_vector(self.formulation.weights)",
    ),
    Mutation(
        "M30",
        "a Dormand-Prince weight of the C integrators (500/1113 -> 500/1112)",
        "aev_ocp/c/dopri5.h",
        "DP_B[6] = {35.0/384, 0, 500.0/1113,",
        "DP_B[6] = {35.0/384, 0, 500.0/1112,",
    ),
    Mutation(
        "M31",
        "optimal-velocity offset 2 -> 2.2",
        "aev_ocp/models/carfollowing.py",
        "return ca.tanh(h - 2.0) + TANH2",
        "return ca.tanh(h - 2.2) + TANH2",
    ),
    Mutation(
        "M32",
        "plant checks the gap row for negative speed",
        "aev_ocp/plant.py",
        '"v": M[n : 2 * n],',
        '"v": M[:n],',
    ),
    Mutation(
        "M33",
        "paper leader amplitude 1.65/1.37 -> 1.37/1.65",
        "aev_ocp/models/leader.py",
        "amplitude: float = 1.65 / 1.37",
        "amplitude: float = 1.37 / 1.65",
    ),
    Mutation(
        "M34",
        "collocation's Lagrange quadrature without the interval length",
        "aev_ocp/ocp/transcription.py",
        "J = J + B[j] * ell(Xc[j]) * h",
        "J = J + B[j] * ell(Xc[j])",
    ),
    Mutation(
        "M35",
        "plant's jerk: leader time derivative scaled by L, not 1/L",
        "aev_ocp/plant.py",
        "jerk = ca.jtimes(a, ca.vertcat(h, v), ca.vertcat(hdot, a)) + ca.jacobian(a, s) / p[1]",
        "jerk = ca.jtimes(a, ca.vertcat(h, v), ca.vertcat(hdot, a)) + ca.jacobian(a, s) * p[1]",
    ),
    Mutation(
        "M36",
        "cascade's jerk without the predecessor-acceleration term",
        "aev_ocp/simulate.py",
        "jerk = ca.jacobian(a, h) * hdot + ca.jacobian(a, v) * a + ca.jacobian(a, vl) * al",
        "jerk = ca.jacobian(a, h) * hdot + ca.jacobian(a, v) * a",
    ),
    Mutation(
        "M37",
        "RMS metrics: square root taken before dividing by the duration",
        "aev_ocp/metrics.py",
        "math.sqrt(max(float(c[-1, i]), 0.0) / duration)",
        "math.sqrt(max(float(c[-1, i]), 0.0)) / duration",
    ),
    # issue 41: the modules of the last wave, each against its own test files first
    Mutation(
        "M38",
        "safe fallback: the lead's measured acceleration enters with the wrong sign",
        "aev_ocp/safety/bound.py",
        "b_l = max(p.lead_brake_mps2, -a_lead_mps2)",
        "b_l = max(p.lead_brake_mps2, a_lead_mps2)",
        "sign",
        ("tests/test_fallback_bound.py", "tests/test_safety.py"),
    ),
    Mutation(
        "M39",
        "safe fallback: the stopping point's mid-step peak left out (end-of-step check)",
        "aev_ocp/safety/bound.py",
        "            cands.append(t_star)",
        "            cands.append(0.0)",
        "missing term",
        ("tests/test_fallback_bound.py", "tests/test_safety.py"),
    ),
    Mutation(
        "M40",
        "safe fallback: the lag's worst delay without a_max",
        "aev_ocp/safety/bound.py",
        "p.lag_s * (p.a_max_mps2 + p.ego_brake_mps2) / p.ego_brake_mps2",
        "p.lag_s * p.ego_brake_mps2 / p.ego_brake_mps2",
        "missing term",
        ("tests/test_fallback_bound.py", "tests/test_safety.py"),
    ),
    Mutation(
        "M41",
        "EKF battery update: Joseph form without K R K'",
        "aev_ocp/estimation/base.py",
        "Pb_n = IKC @ Pb @ IKC.T + Kb @ R[0, 0] @ Kb.T",
        "Pb_n = IKC @ Pb @ IKC.T",
        "missing term",
        ("tests/test_ekf.py", "tests/test_estimation.py"),
    ),
    Mutation(
        "M42",
        "EKF battery prediction: A' P A for A P A'",
        "aev_ocp/estimation/base.py",
        "Pb = A[b, b] @ P[b, b] @ A[b, b].T + Q[b, b]",
        "Pb = A[b, b].T @ P[b, b] @ A[b, b] + Q[b, b]",
        "swapped order",
        ("tests/test_ekf.py", "tests/test_estimation.py"),
    ),
    Mutation(
        "M43",
        "EKF battery prediction without the process noise",
        "aev_ocp/estimation/base.py",
        "Pb = A[b, b] @ P[b, b] @ A[b, b].T + Q[b, b]",
        "Pb = A[b, b] @ P[b, b] @ A[b, b].T",
        "missing term",
        ("tests/test_ekf.py", "tests/test_estimation.py"),
    ),
    Mutation(
        "M44",
        "ring integrator: per-vehicle error times LOCAL_FACTOR, not divided",
        "aev_ocp/c/ring.c",
        "e2 = sqrt(e2 / NCTRL) / LOCAL_FACTOR;",
        "e2 = sqrt(e2 / NCTRL) * LOCAL_FACTOR;",
        "wrong norm",
        ("tests/test_ring_integrator.py", "tests/test_ring.py"),
    ),
    Mutation(
        "M45",
        "ring integrator: ring RMS without 1/n",
        "aev_ocp/c/ring.c",
        "sqrt(sum2 / ((double)n * NCTRL))",
        "sqrt(sum2 / NCTRL)",
        "wrong norm",
        ("tests/test_ring_integrator.py", "tests/test_ring.py"),
    ),
    Mutation(
        "M46",
        "ring integrator: per-vehicle root of the sum, not of the mean",
        "aev_ocp/c/ring.c",
        "e2 = sqrt(e2 / NCTRL) / LOCAL_FACTOR;",
        "e2 = sqrt(e2) / LOCAL_FACTOR;",
        "wrong norm",
        ("tests/test_ring_integrator.py", "tests/test_ring.py"),
    ),
    Mutation(
        "M47",
        "SUMO battery: the current recorded one sample late",
        "aev_ocp/sumo/run.py",
        "        tr.current[-1] = float(I[j])  # the current at the start of the step belongs to the previous sample",
        "        pass",
        "sample shift",
        ("tests/test_sumo_battery.py",),
    ),
    Mutation(
        "M48",
        "SUMO battery: stepped from the step's end speed",
        "aev_ocp/sumo/run.py",
        "x1, I, disc = energy.step(ev, x, u.speed_from_si(v0), u.accel_from_si(a), dt)",
        "x1, I, disc = energy.step(ev, x, u.speed_from_si(v1), u.accel_from_si(a), dt)",
        "sample shift",
        ("tests/test_sumo_battery.py",),
    ),
    Mutation(
        "M49",
        "equal-distance cut: a standstill at the cut distance cut at its last sample",
        "aev_ocp/truncation.py",
        'k = int(np.searchsorted(d, distance, side="left"))',
        'k = int(np.searchsorted(d, distance, side="right"))',
        "sample shift",
        ("tests/test_truncation.py", "tests/test_formulation.py"),
    ),
    Mutation(
        "M50",
        "study profile: a repeated distance takes the heat of the next sample",
        "aev_ocp/truncation.py",
        "        q = q[first]",
        "        q = q[np.minimum(first + 1, q.size - 1)]",
        "sample shift",
        ("tests/test_truncation.py", "tests/test_formulation.py"),
    ),
    Mutation(
        "M51",
        "distance cut: the Hermite slopes of the interval swapped",
        "aev_ocp/truncation.py",
        "v0, v1 = r.speed[k - 1, i], r.speed[k, i]",
        "v1, v0 = r.speed[k - 1, i], r.speed[k, i]",
        "swapped order",
        ("tests/test_truncation.py", "tests/test_formulation.py"),
    ),
    Mutation(
        "M52",
        "battery life: years to 80 % interpolated in the wrong order",
        "aev_ocp/life.py",
        "[q[k], q[k - 1]], [yrs[k], yrs[k - 1]]",
        "[q[k], q[k - 1]], [yrs[k - 1], yrs[k]]",
        "swapped order",
        ("tests/test_life_years.py", "tests/test_life.py"),
    ),
    Mutation(
        "M53",
        "battery life: the last sample below 80 %, not the first",
        "aev_ocp/life.py",
        "k = int(below[0])",
        "k = int(below[-1])",
        "sample shift",
        ("tests/test_life_years.py", "tests/test_life.py"),
    ),
    Mutation(
        "M54",
        "user problem: a traffic-family problem taken for a custom one",
        "aev_ocp/ocp/formulation.py",
        'return "traffic" if obj == "traffic" else',
        'return "custom" if obj == "traffic" else',
        "other",
        ("tests/test_problem_formulation.py", "tests/test_formulation.py"),
    ),
    Mutation(
        "M55",
        "user problem: a custom problem starts cold like §9",
        "aev_ocp/ocp/formulation.py",
        'return self.family != "s9"',
        'return self.family == "traffic"',
        "other",
        ("tests/test_problem_formulation.py", "tests/test_formulation.py"),
    ),
    Mutation(
        "M56",
        "user problem: a built problem's a bounds read lower for upper",
        "aev_ocp/ocp/formulation.py",
        'float(p.u_lb[cn.index("a")]), float(p.u_ub[cn.index("a")])',
        'float(p.u_ub[cn.index("a")]), float(p.u_lb[cn.index("a")])',
        "swapped order",
        ("tests/test_problem_formulation.py", "tests/test_formulation.py"),
    ),
    Mutation(
        "M57",
        "ring stability: wave speed with the phase's sign flipped",
        "aev_ocp/ring/stability.py",
        "float(u.speed_to_si(v)) + s * best_lam.imag / theta",
        "float(u.speed_to_si(v)) - s * best_lam.imag / theta",
        "sign",
        ("tests/test_ring_waves.py", "tests/test_ring.py"),
    ),
    Mutation(
        "M58",
        "ring stability: wave speed without the flow's speed v*",
        "aev_ocp/ring/stability.py",
        "float(u.speed_to_si(v)) + s * best_lam.imag / theta",
        "s * best_lam.imag / theta",
        "missing term",
        ("tests/test_ring_waves.py", "tests/test_ring.py"),
    ),
    Mutation(
        "M59",
        "declared ranges: a closed lower limit refuses the limit itself",
        "aev_ocp/params.py",
        "and (self.ge is None or x >= self.ge)",
        "and (self.ge is None or x > self.ge)",
        "wrong limit",
        ("tests/test_range_boundaries.py", "tests/test_declared_validation.py"),
    ),
    Mutation(
        "M60",
        "declared ranges: an open upper limit accepts the limit itself",
        "aev_ocp/params.py",
        "and (self.lt is None or x < self.lt)",
        "and (self.lt is None or x <= self.lt)",
        "wrong limit",
        ("tests/test_range_boundaries.py", "tests/test_declared_validation.py"),
    ),
    Mutation(
        "M61",
        "declared ranges: a closed upper limit refuses the limit itself",
        "aev_ocp/params.py",
        "and (self.le is None or x <= self.le)",
        "and (self.le is None or x < self.le)",
        "wrong limit",
        ("tests/test_range_boundaries.py", "tests/test_declared_validation.py"),
    ),
)


@dataclass
class Outcome:
    key: str
    what: str
    path: str
    caught: bool
    stage: str
    first_failure: str
    message: str
    seconds: float
    kind: str = "other"


def repo_files(root: Path) -> list[str]:
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split("\n")
    return [f for f in out if f and (root / f).is_file()]


def make_copy(root: Path, files: list[str], dest: Path) -> None:
    for f in files:
        d = dest / f
        d.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / f, d)


def apply(dest: Path, m: Mutation) -> None:
    p = dest / m.path
    text = p.read_text()
    n = text.count(m.old)
    if n != 1:
        raise SystemExit(f"{m.key}: the text to mutate occurs {n} times in {m.path} (expected once): {m.old!r}")
    p.write_text(text.replace(m.old, m.new))


def first_failure(out: str) -> tuple[str, str]:
    """(first failing test, its message): the short-summary line and the first 'E' lines of the report
    (they show how far the checked number moved)."""
    lines = out.splitlines()
    e_lines = [ln[1:].strip() for ln in lines if ln.startswith("E ") and ln[1:].strip()]
    detail = " | ".join(e_lines[:3])
    for line in lines:
        mm = re.match(r"^(FAILED|ERROR) (\S+)(?: - (.*))?$", line)
        if mm:
            msg = (mm.group(3) or "").strip()
            return mm.group(2), (detail or msg)[:400]
    tail = [ln for ln in lines if ln.strip()][-1:] or [""]
    return "?", (detail or tail[0])[:400]


def run_pytest(cwd: Path, args: list[str], timeout: float) -> tuple[int, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    try:
        p = subprocess.run([*PYTEST, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout + p.stderr
    except subprocess.TimeoutExpired as exc:
        return -1, f"TIMEOUT after {timeout:.0f} s\n{exc.stdout or ''}"


def run_one(m: Mutation | None, files: list[str], full: bool, timeout: float, own_only: bool = False) -> Outcome:
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="aev_mut_") as tmp:
        dest = Path(tmp)
        make_copy(ROOT, files, dest)
        if m is not None:
            apply(dest, m)
        own = list(m.tests) if m is not None and m.tests else list(FAST_FILES)
        stages = [] if full else [("own" if m is not None and m.tests else "fast", own)]
        if not own_only or full:
            stages.append(("suite", ["-n", "2"]))
        caught, stage, name, msg = False, "suite", "", ""
        for stage, args in stages:
            rc, out = run_pytest(dest, args, timeout)
            if rc != 0:
                caught = True
                name, msg = first_failure(out)
                if rc == -1:
                    name, msg = "(timeout)", out.splitlines()[0]
                break
    key, what, path = (m.key, m.what, m.path) if m else ("base", "no mutation (baseline)", "-")
    kind = m.kind if m else "-"
    return Outcome(key, what, path, caught, stage, name, msg, time.perf_counter() - t0, kind)


def table(rows: list[Outcome]) -> str:
    head = (
        f"{'key':<5} {'class':<13} {'mutation':<58} {'file':<30} {'caught':<8} {'stage':<6} {'s':>6}"
        "  first failing test"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        mark = ("FAILS" if r.caught else "passes") if r.key == "base" else ("killed" if r.caught else "SURVIVED")
        lines.append(
            f"{r.key:<5} {r.kind:<13} {r.what[:58]:<58} {r.path:<30} {mark:<8} {r.stage:<6} {r.seconds:6.0f}"
            f"  {r.first_failure}"
        )
    return "\n".join(lines)


def by_kind(rows: list[Outcome]) -> str:
    """Killed/survived per bug class."""
    lines = []
    for kind in KINDS:
        sel = [r for r in rows if r.key != "base" and r.kind == kind]
        if sel:
            k = sum(r.caught for r in sel)
            lines.append(f"{kind:<13} {k:>3} killed {len(sel) - k:>3} survived")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", help="mutation keys to run (default: all)")
    ap.add_argument("--full", action="store_true", help="skip the fast stage (whole suite for every mutation)")
    ap.add_argument("--baseline", action="store_true", help="also run the unmutated suite first (must pass)")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--kind", nargs="*", choices=KINDS, help="only the mutations of these bug classes")
    ap.add_argument(
        "--own",
        action="store_true",
        help="only each mutation's own test files (its module's tests; FAST_FILES for the older ones), no suite",
    )
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per pytest run")
    ap.add_argument("--json", default=str(ROOT / "benchmarks" / "mutation.json"))
    a = ap.parse_args()
    todo = [m for m in MUTATIONS if (not a.only or m.key in a.only) and (not a.kind or m.kind in a.kind)]
    if a.list:
        for m in todo:
            own = " ".join(m.tests) if m.tests else "(fast files)"
            print(f"{m.key:<5} {m.kind:<13} {m.path:<32} {m.what}  [{own}]")
        return 0
    files = repo_files(ROOT)
    for m in todo:  # fail early on a stale mutation (text not found)
        text = (ROOT / m.path).read_text()
        if text.count(m.old) != 1:
            raise SystemExit(f"{m.key}: {m.old!r} occurs {text.count(m.old)} times in {m.path}")
    rows: list[Outcome] = []
    t0 = time.perf_counter()
    plan: list[Mutation | None] = ([None] if a.baseline else []) + list(todo)
    for m in plan:
        r = run_one(m, files, a.full or m is None, a.timeout, a.own)
        rows.append(r)
        verdict = (
            ("FAILS (the unmutated suite must pass)" if r.caught else "passes")
            if m is None
            else ("caught" if r.caught else "SURVIVED")
        )
        print(
            f"[{time.perf_counter() - t0:7.0f} s] {r.key}: {verdict} "
            f"({r.stage}, {r.seconds:.0f} s) {r.first_failure} {r.message[:160]}",
            flush=True,
        )
    print()
    print(table(rows))
    total = time.perf_counter() - t0
    n_mut = sum(1 for r in rows if r.key != "base")
    n_caught = sum(1 for r in rows if r.key != "base" and r.caught)
    print()
    print(by_kind(rows))
    print(f"\n{n_caught}/{n_mut} mutations caught in {total:.0f} s")
    out = {
        "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "total_s": total,
        "python": sys.version.split()[0],
        "cpus": os.cpu_count(),
        "fast_files": list(FAST_FILES),
        "results": [asdict(r) for r in rows],
    }
    tmp = Path(a.json).with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=2) + "\n")
    tmp.replace(a.json)
    base_ok = all(not r.caught for r in rows if r.key == "base")
    return 0 if base_ok and n_caught == n_mut else 1


if __name__ == "__main__":
    sys.exit(main())
