"""Platoon simulation with closed-form car-following laws and each vehicle's battery in the loop.

State per follower: gap h, speed v (model units), and the cell's V1, V2 [V], S [-]; cumulative
integrals per follower: the paper's ω, pack ∫Q and ∫Q_irr [J], and the integrals of squared
tracking errors and jerk. Two interchangeable integrators (SimOptions.method):

* "cascade" (default when a C compiler works): vehicle i depends only on vehicle i − 1, so the
  platoon is integrated vehicle by vehicle in compiled code (CasADi-generated C for each law and the
  leader plus a small Dormand–Prince 5(4) driver, compiled once with gcc and cached by content hash).
  Each vehicle gets its own adaptive steps (cost ~linear in the platoon size, each integration only
  resolves its own kinks); its leader's speed and acceleration are the predecessor's quartic dense
  output, accurate to the tolerance. ω is computed exactly as A·Δ(v²/2) + B·TV(v²/2) (g = A u + B|u|),
  so the kink of g at v̇ = 0 costs no steps; steps end at gap extrema (v_l = v), where the proposed
  law's ε term switches sharply, so the error estimate sees that feature instead of stepping over it.
  Events are checked after every step and located on the dense output (bisection).
* "cvodes": the whole platoon as one CasADi SX expression integrated by CVODES (the fallback when no
  compiler is available). Time is normalised inside the integrator (dx/ds = L·f(t0 + L s, x),
  s ∈ [0, 1], p = (t0, L)), so ONE integrator Function serves every chunk; after each chunk the
  samples are checked.

Both split the timeline exactly at the leader's breakpoints (e.g. the paper leader's t = 20) and
check for collision (h ≤ 0), negative speed, an infeasible current demand (E² < 4 R_s P_c) and S
leaving [0, 1]. The first such event stops the run and is reported with its time and vehicle —
nothing is integrated through (in the cascade, later vehicles are integrated only up to the
earliest event so far).
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from .compiled import compile_shared
from .models import battery, energy
from .models.carfollowing import CarFollowingLaw, optimal_velocity
from .models.leader import LeaderProfile
from .models.powertrain import cell_current_from_motion
from .params import METHODS, EVParams, ParameterError, SimOptions
from .results import Event, SimulationResult

ProgressFn = Callable[[float, float], None]
_EVENT_KINDS = {1: ("collision", "gap h reached 0"), 2: ("negative_speed", "speed became negative"),
                3: ("infeasible_current", "cell cannot deliver the power demand (E² < 4 R_s P_c)"),
                4: ("soc_out_of_range", "state of charge fell below 0"),
                5: ("soc_out_of_range", "state of charge rose above 1")}


def cell_rates(v: Any, a: Any, V1: Any, V2: Any, S: Any, ev: EVParams) -> dict[str, Any]:
    """Battery side of one vehicle for model speed v and acceleration a (exact η switch).

    Returns dV1, dV2 [V/s], dS [1/s], heat_W and heat_irr_W (pack [W]), I [A], disc [V²].
    """
    u = ev.units
    # S is clamped to the OCV table's range and the discriminant floored at 1e-12 V² inside the
    # right-hand side only, so that the integrator stays finite up to an event; the simulator checks
    # the true S and discriminant at every sample and stops at the first violation.
    S_in = ca.fmin(ca.fmax(S, 0.0), 1.0)
    cm = cell_current_from_motion(u.speed_to_si(v), u.accel_to_si(a), V1, V2, S_in, ev)
    I = 2.0 * cm["P_c"] / (cm["E"] + ca.sqrt(ca.fmax(cm["disc"], 1e-12)))
    dV1, dV2, dS = battery.cell_derivatives(V1, V2, I, ev.cell)
    n = ev.pack.n_cells
    return {"dV1": dV1, "dV2": dV2, "dS": dS, "I": I, "disc": cm["disc"],
            "heat_W": n * battery.heat_Q(V1, V2, I, ev.cell),
            "heat_irr_W": n * battery.heat_irreversible(V1, V2, I, ev.cell)}


def cell_rates_function(ev: EVParams) -> ca.Function:
    """:func:`cell_rates` as a scalar SX Function (v, a, V1, V2, S) -> (dV1, dV2, dS, heat_W, heat_irr_W, I, disc)."""
    v, a, V1, V2, S = (ca.SX.sym(n) for n in ("v", "a", "V1", "V2", "S"))
    r = cell_rates(v, a, V1, V2, S, ev)
    names = ["dV1", "dV2", "dS", "heat_W", "heat_irr_W", "I", "disc"]
    return ca.Function("cell_rates", [v, a, V1, V2, S], [r[k] for k in names],
                       ["v", "a", "V1", "V2", "S"], names)


_CASCADE_C = r"""
/* ---------------- aev_ocp cascade driver (appended to the CasADi-generated RHS) ----------------
 * Vehicle i depends only on vehicle i-1, so the platoon is integrated vehicle by vehicle with an
 * adaptive Dormand-Prince 5(4) method (coefficients as in Dormand & Prince 1980 / SciPy RK45, quartic
 * dense output). The predecessor's speed v_l(t) and acceleration a_l(t) are its own dense output.
 * All z = (x, quadratures) are in the error norm (like CVODES with quad_err_con).          */
#include <stdlib.h>
#include <string.h>
#define NZ (NX + NQ)
#define NCOL (NZ + NY)

typedef struct { const casadi_real* arg[SZ_ARG]; casadi_real* res[SZ_RES]; casadi_int iw[SZ_IW + 1]; casadi_real w[SZ_W + 1]; } aev_ctx;
typedef struct { long m, cap, cur; double *t0, *h, *v0, *q; } aev_traj;

static const double DP_C[7] = {0.0, 1.0/5, 3.0/10, 4.0/5, 8.0/9, 1.0, 1.0};
static const double DP_A[6][5] = {
  {0, 0, 0, 0, 0}, {1.0/5, 0, 0, 0, 0}, {3.0/40, 9.0/40, 0, 0, 0}, {44.0/45, -56.0/15, 32.0/9, 0, 0},
  {19372.0/6561, -25360.0/2187, 64448.0/6561, -212.0/729, 0},
  {9017.0/3168, -355.0/33, 46732.0/5247, 49.0/176, -5103.0/18656}};
static const double DP_B[6] = {35.0/384, 0, 500.0/1113, 125.0/192, -2187.0/6784, 11.0/84};
static const double DP_E[7] = {-71.0/57600, 0, 71.0/16695, -71.0/1920, 17253.0/339200, -22.0/525, 1.0/40};
static const double DP_P[7][4] = {
  {1, -8048581381.0/2820520608, 8663915743.0/2820520608, -12715105075.0/11282082432},
  {0, 0, 0, 0},
  {0, 131558114200.0/32700410799, -68118460800.0/10900136933, 87487479700.0/32700410799},
  {0, -1754552775.0/470086768, 14199869525.0/1410260304, -10690763975.0/1880347072},
  {0, 127303824393.0/49829197408, -318862633887.0/49829197408, 701980252875.0/199316789632},
  {0, -282668133.0/205662961, 2019193451.0/616988883, -1453857185.0/822651844},
  {0, 40617522.0/29380423, -110615467.0/29380423, 69997945.0/29380423}};

static int aev_law(aev_ctx* c, int law, const double* u, const double* x, double* dz, double* y) {
  c->arg[0] = u; c->arg[1] = x; c->res[0] = dz; c->res[1] = y;
  switch (law) {
LAW_SWITCH
  }
  return 1;
}

static void aev_leader(aev_ctx* c, double t, double* u) {
  c->arg[0] = &t; c->res[0] = u;
  aevsim_leader(c->arg, c->res, c->iw, c->w, 0);
}

static int aev_push(aev_traj* p, double t0, double h, double v0, const double* q) {
  if (p->m == p->cap) {
    long cap = p->cap ? 2 * p->cap : 1024;
    double* a = realloc(p->t0, cap * sizeof(double)); if (!a) return 1; p->t0 = a;
    a = realloc(p->h, cap * sizeof(double)); if (!a) return 1; p->h = a;
    a = realloc(p->v0, cap * sizeof(double)); if (!a) return 1; p->v0 = a;
    a = realloc(p->q, 4 * cap * sizeof(double)); if (!a) return 1; p->q = a;
    p->cap = cap;
  }
  p->t0[p->m] = t0; p->h[p->m] = h; p->v0[p->m] = v0; memcpy(p->q + 4 * p->m, q, 4 * sizeof(double));
  p->m++;
  return 0;
}

/* predecessor speed and acceleration at t from its dense output */
static void aev_traj_eval(aev_traj* p, double t, double* u) {
  long j = p->cur;
  while (j < p->m - 1 && t > p->t0[j] + p->h[j]) j++;
  while (j > 0 && t < p->t0[j]) j--;
  p->cur = j;
  double h = p->h[j], th = (t - p->t0[j]) / h;
  if (th < 0) th = 0; if (th > 1) th = 1;
  const double* q = p->q + 4 * j;
  u[0] = p->v0[j] + h * th * (q[0] + th * (q[1] + th * (q[2] + th * q[3])));
  u[1] = q[0] + th * (2 * q[1] + th * (3 * q[2] + th * 4 * q[3]));
}

static void aev_input(aev_ctx* c, aev_traj* prev, int i, double t, double* u) {
  if (i == 0) aev_leader(c, t, u); else aev_traj_eval(prev, t, u);
}

static void aev_dense(const double* z, const double (*Q)[4], double h, double th, double* out) {
  for (int k = 0; k < NZ; k++)
    out[k] = z[k] + h * th * (Q[k][0] + th * (Q[k][1] + th * (Q[k][2] + th * Q[k][3])));
}

/* first theta in (0, 1] where component k of the dense output (plus off) becomes <= 0 (bisection) */
static double aev_root(const double* z, const double (*Q)[4], double h, int k, double sign, double off) {
  double lo = 0, hi = 1, buf[NZ];
  for (int it = 0; it < 60; it++) {
    double mid = 0.5 * (lo + hi);
    aev_dense(z, Q, h, mid, buf);
    if (sign * buf[k] + off > 0) lo = mid; else hi = mid;
  }
  return hi;
}

/* Exact ω over [0, th_end] of a step: with g(u) = A u + B |u| (A = (1/η + η)/2, B = (1/η − η)/2) and
 * v ≥ 0, v g(v̇) = A d(v²/2)/dt + B |d(v²/2)/dt|, so ω = A Δ(v²/2) + B · (total variation of v²/2),
 * and the variation only needs v at the zeros of v̇ — located on the quartic dense output of v.
 * This removes the kink of g at v̇ = 0 from the quadrature (no tiny steps around it). */
static double aev_vpoly(double v0, const double* q, double h, double th) {
  return v0 + h * th * (q[0] + th * (q[1] + th * (q[2] + th * q[3])));
}
static double aev_dvpoly(const double* q, double th) {
  return q[0] + th * (2 * q[1] + th * (3 * q[2] + th * 4 * q[3]));
}
static double aev_omega_inc(double v0, const double* q, double h, double th_end) {
  /* split [0, th_end] where dv/dθ is monotone (zeros of its derivative), bisect each sign change */
  double cut[5]; int nc = 0;
  cut[nc++] = 0;
  double a2 = 12 * q[3], a1 = 6 * q[2], a0 = 2 * q[1], r[2]; int nr = 0;
  if (fabs(a2) > 1e-300) {
    double d = a1 * a1 - 4 * a2 * a0;
    if (d > 0) { double sq = sqrt(d); r[0] = (-a1 - sq) / (2 * a2); r[1] = (-a1 + sq) / (2 * a2); nr = 2;
                 if (r[0] > r[1]) { double tt = r[0]; r[0] = r[1]; r[1] = tt; } }
  } else if (fabs(a1) > 1e-300) { r[0] = -a0 / a1; nr = 1; }
  for (int j = 0; j < nr; j++) if (r[j] > 0 && r[j] < th_end) cut[nc++] = r[j];
  cut[nc++] = th_end;
  double tv = 0, w_prev = 0.5 * v0 * v0;
  for (int j = 0; j + 1 < nc; j++) {
    double lo = cut[j], hi = cut[j + 1], flo = aev_dvpoly(q, lo), fhi = aev_dvpoly(q, hi);
    if ((flo > 0 && fhi < 0) || (flo < 0 && fhi > 0)) {
      for (int it = 0; it < 45; it++) {
        double mid = 0.5 * (lo + hi), fm = aev_dvpoly(q, mid);
        if ((fm > 0) == (flo > 0)) { lo = mid; flo = fm; } else hi = mid;
      }
      double th = 0.5 * (lo + hi), vv = aev_vpoly(v0, q, h, th), w = 0.5 * vv * vv;
      tv += fabs(w - w_prev); w_prev = w;
    }
  }
  double ve = aev_vpoly(v0, q, h, th_end), we = 0.5 * ve * ve;
  tv += fabs(we - w_prev);
  return OMEGA_A * (we - 0.5 * v0 * v0) + OMEGA_B * tv;
}

/* Returns 0 on success, 1 on out-of-memory. Event kinds: 0 none, 1 collision, 2 negative_speed,
 * 3 infeasible_current, 4 soc below 0, 5 soc above 1, 6 integration failed. */
CASADI_SYMBOL_EXPORT int aevsim_run(int n, const int* law_idx, const double* x0, int nstop, const double* stops,
    int K, const double* ts, double rtol, double atol, long max_steps,
    double* out, int* nsamp, int* ev_kind, double* ev_time, double* ev_val, long* stats) {
  aev_ctx* c = malloc(sizeof(aev_ctx));
  aev_traj tr[2] = {{0}, {0}};
  if (!c) return 1;
  double tmax = stops[nstop - 1];
  int status = 0;
  for (int i = 0; i < n && !status; i++) {
    aev_traj* prev = &tr[(i + 1) % 2];
    aev_traj* cur = &tr[i % 2];
    cur->m = 0; cur->cur = 0; prev->cur = 0;
    int law = law_idx[i];
    double z[NZ], zn[NZ], zt[NZ], k[7][NZ], Q[NZ][4], y[NY], yn[NY], u[2], err, tmp[NZ];
    double* o = out + (long)i * K * NCOL;
    long nst = 0, nrej = 0, nfev = 0;
    int s = 0, kind = 0, istop = 0;
    double t = 0, tev = INFINITY, val = 0;
    for (int j = 0; j < NX; j++) z[j] = x0[i * NX + j];
    for (int j = NX; j < NZ; j++) z[j] = 0;
    aev_input(c, prev, i, t, u); aev_law(c, law, u, z, k[0], y); nfev++;
    /* sample at t = 0 and the initial check */
    memcpy(o, z, NZ * sizeof(double)); memcpy(o + NZ, y, NY * sizeof(double)); s = 1;
    if (y[2] < 0) { kind = 3; tev = 0; val = y[2]; }
    if (BATTERY && z[4] < 0) { kind = 4; tev = 0; val = z[4]; }
    if (BATTERY && z[4] > 1) { kind = 5; tev = 0; val = z[4]; }
    double h = 1e-4;
    while (!kind && t < tmax) {
      while (istop < nstop - 1 && stops[istop] <= t) istop++;
      double tstop = stops[istop] < tmax ? stops[istop] : tmax;
      int hit = 0;
      if (t + h >= tstop - 1e-12 * (1 + fabs(tstop))) { h = tstop - t; hit = 1; }
      for (int st = 1; st < 6; st++) {
        for (int j = 0; j < NZ; j++) {
          double acc = 0; for (int l = 0; l < st; l++) acc += DP_A[st][l] * k[l][j];
          zt[j] = z[j] + h * acc;
        }
        aev_input(c, prev, i, t + DP_C[st] * h, u); aev_law(c, law, u, zt, k[st], tmp);
      }
      for (int j = 0; j < NZ; j++) {
        double acc = 0; for (int l = 0; l < 6; l++) acc += DP_B[l] * k[l][j];
        zn[j] = z[j] + h * acc;
      }
      aev_input(c, prev, i, t + h, u); aev_law(c, law, u, zn, k[6], yn); nfev += 6;
      double nrm = 0;
      for (int j = 0; j < NZ; j++) {
        if (j == NX) continue;  /* ω is computed exactly from v below */
        double e = 0; for (int l = 0; l < 7; l++) e += DP_E[l] * k[l][j];
        double sc = atol + rtol * fmax(fabs(z[j]), fabs(zn[j]));
        e = h * e / sc; nrm += e * e;
      }
      nrm = sqrt(nrm / (NZ - 1));
      if (!isfinite(nrm)) nrm = INFINITY;
      if (nrm > 1) {
        nrej++;
        h *= fmax(0.2, 0.9 * pow(nrm, -0.2));
        if (h < 1e-14 * (1 + fabs(t)) || nst + nrej > max_steps) { kind = 6; tev = t; val = z[0]; }
        continue;
      }
      for (int j = 0; j < NZ; j++)
        for (int m = 0; m < 4; m++) {
          double acc = 0; for (int l = 0; l < 7; l++) acc += k[l][j] * DP_P[l][m];
          Q[j][m] = acc;
        }
      /* Gap extrema (v_l − v = 0) are where laws like the proposed one switch sharply (the ε term
       * has width ~sqrt(ε) in v_l − v): end the step at the crossing so the next step starts on the
       * feature and its error estimate sees it, instead of stepping over it between stages. */
      {
        int cross = 0;
        for (int l = 1; l < 7; l++) if ((k[l][0] > 0) != (k[0][0] > 0)) cross = 1;
        if (cross) {
          double lo = 0, hi = 1, flo = aev_dvpoly(Q[0], 0.0);
          double fhi = aev_dvpoly(Q[0], 1.0);
          if ((flo > 0) != (fhi > 0)) {
            for (int it = 0; it < 40; it++) {
              double mid = 0.5 * (lo + hi), fm = aev_dvpoly(Q[0], mid);
              if ((fm > 0) == (flo > 0)) lo = mid; else hi = mid;
            }
          } else hi = 0;
          if (hi > 1e-3 && hi < 0.999 && h * hi > 1e-12 * (1 + fabs(t))) { h *= hi; nrej++; continue; }
        }
      }
      zn[NX] = z[NX] + aev_omega_inc(z[1], Q[1], h, 1.0);
      if (i < n - 1 && aev_push(cur, t, h, z[1], Q[1])) { status = 1; break; }
      /* events at the step end, located inside the step on the dense output */
      double th_ev = 2;
      if (zn[0] <= 0) { double th = aev_root(z, Q, h, 0, 1, 0); if (th < th_ev) { th_ev = th; kind = 1; val = zn[0]; } }
      if (zn[1] < -1e-9) { double th = aev_root(z, Q, h, 1, 1, 1e-9); if (th < th_ev) { th_ev = th; kind = 2; val = zn[1]; } }
      if (yn[2] < 0) { double th = y[2] > 0 ? y[2] / (y[2] - yn[2]) : 0; if (th < th_ev) { th_ev = th; kind = 3; val = yn[2]; } }
      if (BATTERY && zn[4] < 0) { double th = aev_root(z, Q, h, 4, 1, 0); if (th < th_ev) { th_ev = th; kind = 4; val = zn[4]; } }
      if (BATTERY && zn[4] > 1) { double th = aev_root(z, Q, h, 4, -1, 1); if (th < th_ev) { th_ev = th; kind = 5; val = zn[4]; } }
      double tend = hit ? tstop : t + h;
      if (kind) tev = t + th_ev * h;
      double tlim = kind ? tev : tend;
      while (s < K && (kind ? ts[s] < tlim : ts[s] <= tlim + 1e-12 * (1 + fabs(tlim)))) {
        double th = (ts[s] - t) / h, us[2], dz[NZ];
        if (th > 1) th = 1;
        double* os = o + (long)s * NCOL;
        aev_dense(z, Q, h, th, os);
        os[NX] = z[NX] + aev_omega_inc(z[1], Q[1], h, th);
        aev_input(c, prev, i, ts[s], us); aev_law(c, law, us, os, dz, os + NZ); nfev++;
        s++;
      }
      nst++;
      if (kind) break;
      t = tend;
      memcpy(z, zn, sizeof z); memcpy(y, yn, sizeof y); memcpy(k[0], k[6], sizeof k[0]);
      if (hit && t < tmax) {  /* restart at a breakpoint: the leader's acceleration may jump there */
        aev_input(c, prev, i, t, u); aev_law(c, law, u, z, k[0], y); nfev++;
      }
      h *= nrm == 0 ? 10 : fmin(10, 0.9 * pow(nrm, -0.2));
      if (nst + nrej > max_steps) { kind = 6; tev = t; val = z[0]; }
    }
    nsamp[i] = s; ev_kind[i] = kind; ev_time[i] = kind ? tev : t; ev_val[i] = val;
    stats[3 * i] = nst; stats[3 * i + 1] = nrej; stats[3 * i + 2] = nfev;
    if (kind && tev < tmax) tmax = tev;
  }
  for (int j = 0; j < 2; j++) { free(tr[j].t0); free(tr[j].h); free(tr[j].v0); free(tr[j].q); }
  free(c);
  return status;
}
"""



def _compile_shared(source: str) -> tuple[ctypes.CDLL | None, str]:
    """Compile and load the cascade's C source (cached, see :mod:`aev_ocp.compiled`); (None, why) on failure."""
    built = compile_shared(source, "aevsim", "simulate")
    if built.path is None:
        return None, built.error
    try:
        return ctypes.CDLL(str(built.path)), ""
    except OSError as exc:
        return None, f"cannot load {built.path}: {exc}"


def _segments(t_end: float, breakpoints: Sequence[float], chunk: float) -> list[tuple[float, float]]:
    """Intervals covering [0, t_end], split exactly at breakpoints and into pieces of length ≤ chunk."""
    cuts = [0.0] + sorted(b for b in breakpoints if 0.0 < b < t_end) + [t_end]
    out: list[tuple[float, float]] = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        m = max(1, math.ceil((b - a) / chunk - 1e-9))
        edges = np.linspace(a, b, m + 1)
        out.extend(zip(edges[:-1].tolist(), edges[1:].tolist()))
    return out


class PlatoonSimulator:
    """A platoon behind ``leader`` with one law per follower; build once, run many initial conditions.

    Vehicle i (0-based) follows vehicle i − 1; vehicle 0 follows the leader.
    """

    def __init__(self, leader: LeaderProfile, laws: Sequence[CarFollowingLaw], ev: EVParams | None = None,
                 options: SimOptions | None = None, battery: bool = True) -> None:
        if len(laws) < 1:
            raise ParameterError("simulate: the platoon needs at least one follower (laws is empty)")
        self.leader, self.laws = leader, list(laws)
        self.ev = ev or EVParams()
        self.opts = options or SimOptions()
        self.battery = battery
        self.n = len(self.laws)
        self.k = max(1, math.ceil(self.opts.chunk / self.opts.dt_out - 1e-9))
        self._lib: ctypes.CDLL | None = None
        self._build_error = ""
        self._leader_maps: dict[int, ca.Function] = {}
        if self.opts.method in ("auto", "cascade"):
            self._build_cascade()
            if self._lib is None and self.opts.method == "cascade":
                raise ParameterError("SimOptions.method = 'cascade' needs a working C compiler (gcc/cc): "
                                     f"{self._build_error}; use method='cvodes' or 'auto'")
        self.method = "cascade" if self._lib is not None else "cvodes"
        if self.method == "cvodes":
            self._build()

    # ------------------------------------------------------------------ symbolic model
    def _accel_expr(self, h: ca.SX, v: ca.SX, v_lead: ca.SX) -> ca.SX:
        """Accelerations of all followers, vectorised over groups of followers with the same law."""
        a = ca.SX.zeros(self.n)
        groups: dict[CarFollowingLaw, list[int]] = {}
        for i, law in enumerate(self.laws):
            groups.setdefault(law, []).append(i)
        for law, idx in groups.items():
            a[idx] = law.accel(h[idx], v[idx], v_lead[idx])
        return a

    def _build(self) -> None:
        n, ev, T = self.n, self.ev, self.ev.units.time_s
        h, v = ca.SX.sym("h", n), ca.SX.sym("v", n)
        s, p = ca.SX.sym("s"), ca.SX.sym("p", 2)  # normalised time, (t0, L)
        t = p[0] + p[1] * s
        vl = self.leader.speed(t)
        v_lead = ca.vertcat(vl, v[:-1]) if n > 1 else vl
        a = self._accel_expr(h, v, v_lead)
        hdot = v_lead - v
        # jerk = da/dt by the chain rule (forward AD), including the leader's explicit time dependence
        jerk = (ca.jtimes(a, ca.vertcat(h, v), ca.vertcat(hdot, a)) + ca.jacobian(a, s) / p[1])
        eta = ev.vehicle.efficiency
        x = [h, v]
        ode = [hdot, a]
        quad = [v * energy.g_exact(a, eta), (optimal_velocity(h) - v) ** 2, hdot**2, jerk**2]
        if self.battery:
            V1, V2, S = ca.SX.sym("V1", n), ca.SX.sym("V2", n), ca.SX.sym("S", n)
            cr = cell_rates_function(ev).map(n)(v.T, a.T, V1.T, V2.T, S.T)
            dV1, dV2, dS, qW, qirrW, I, disc = (c.T for c in cr)
            x += [V1, V2, S]
            ode += [T * dV1, T * dV2, T * dS]
            quad += [T * qW, T * qirrW]
        else:
            I = disc = ca.SX.zeros(n)
        X, Qd = ca.vertcat(*x), ca.vertcat(*quad)
        dae = {"x": X, "p": p, "t": s, "ode": p[1] * ca.vertcat(*ode), "quad": p[1] * Qd}
        grid = np.linspace(0.0, 1.0, self.k + 1)[1:].tolist()
        iopts = {"abstol": self.opts.atol, "reltol": self.opts.rtol, "max_num_steps": self.opts.max_num_steps,
                 "quad_err_con": True, "disable_internal_warnings": True,
                 "show_eval_warnings": False}
        self.integrator = ca.integrator("platoon", "cvodes", dae, 0.0, grid, iopts)
        tt = ca.SX.sym("t")
        sample = ca.Function("samples", [tt, X], [ca.substitute(ca.vertcat(a, I, disc, vl), ca.vertcat(s, p),
                                                                 ca.vertcat(0, tt, 1))])
        self.samples = sample.map(self.k + 1)
        self.nx = X.numel()


    # ------------------------------------------------------------------ compiled cascade
    def _vehicle_function(self, law: CarFollowingLaw, k: int) -> ca.Function:
        """One follower's right-hand side: (u = (v_l, a_l), x) -> (dz = (ẋ, quadrature integrands), y = (a, I, disc)).

        x = (h, v[, V1, V2, S]) in model units and volts; quadrature integrands per model time unit:
        ω, (V(h) − v)², (v_l − v)², jerk²[, pack Q and Q_irr in J per model time unit]."""
        ev, T, eta = self.ev, self.ev.units.time_s, self.ev.vehicle.efficiency
        u = ca.SX.sym("u", 2)
        vl, al = u[0], u[1]
        h, v = ca.SX.sym("h"), ca.SX.sym("v")
        a = law.accel(h, v, vl)
        hdot = vl - v
        jerk = ca.jacobian(a, h) * hdot + ca.jacobian(a, v) * a + ca.jacobian(a, vl) * al
        x, ode = [h, v], [hdot, a]
        quad = [v * energy.g_exact(a, eta), (optimal_velocity(h) - v) ** 2, hdot**2, jerk**2]
        if self.battery:
            V1, V2, S = ca.SX.sym("V1"), ca.SX.sym("V2"), ca.SX.sym("S")
            cr = cell_rates(v, a, V1, V2, S, ev)
            x += [V1, V2, S]
            ode += [T * cr["dV1"], T * cr["dV2"], T * cr["dS"]]
            quad += [T * cr["heat_W"], T * cr["heat_irr_W"]]
            y = [a, cr["I"], cr["disc"]]
        else:
            y = [a, ca.SX(0), ca.SX(0)]
        return ca.Function(f"aevsim_law{k}", [u, ca.vertcat(*x)], [ca.vertcat(*ode, *quad), ca.vertcat(*y)])

    def _build_cascade(self) -> None:
        """Generate C for each distinct law and the leader, append the cascade driver, compile, load."""
        self._law_of: list[int] = []
        distinct: dict[CarFollowingLaw, int] = {}
        for law in self.laws:
            self._law_of.append(distinct.setdefault(law, len(distinct)))
        funcs = [self._vehicle_function(law, k) for law, k in distinct.items()]
        t = ca.SX.sym("t")
        vl = self.leader.speed(t)
        funcs.append(ca.Function("aevsim_leader", [t], [ca.vertcat(vl, ca.jacobian(vl, t))]))
        self._nx = 5 if self.battery else 2
        self._nq = 6 if self.battery else 4
        cg = ca.CodeGenerator("aevsim_rhs.c", {"with_header": False})
        for f in funcs:
            cg.add(f)
        sizes = {"SZ_ARG": max(2, *(f.sz_arg() for f in funcs)), "SZ_RES": max(2, *(f.sz_res() for f in funcs)),
                 "SZ_IW": max(f.sz_iw() for f in funcs), "SZ_W": max(f.sz_w() for f in funcs)}
        head = "".join(f"#define {k} {v}\n" for k, v in sizes.items())
        eta = self.ev.vehicle.efficiency
        head += f"#define OMEGA_A {0.5 * (1 / eta + eta)!r}\n#define OMEGA_B {0.5 * (1 / eta - eta)!r}\n"
        head += f"#define NX {self._nx}\n#define NQ {self._nq}\n#define NY 3\n#define BATTERY {int(self.battery)}\n"
        switch = "".join(f"    case {k}: return aevsim_law{k}(c->arg, c->res, c->iw, c->w, 0);\n"
                         for k in range(len(distinct)))
        source = cg.dump() + "\n" + head + _CASCADE_C.replace("LAW_SWITCH", switch)
        lib, self._build_error = _compile_shared(source)
        if lib is None:
            return
        fn = lib.aevsim_run
        dp, ip, lp = (np.ctypeslib.ndpointer(dtype=d, flags="C_CONTIGUOUS") for d in (np.float64, np.int32, np.int64))
        fn.argtypes = [ctypes.c_int, ip, dp, ctypes.c_int, dp, ctypes.c_int, dp, ctypes.c_double, ctypes.c_double,
                       ctypes.c_long, dp, ip, ip, dp, dp, lp]
        fn.restype = ctypes.c_int
        self._lib, self._run_c = lib, fn

    def _sample_times(self, t_end: float) -> np.ndarray:
        """The sample grid [model time]: the same chunks of ≤ dt_out as the CVODES path."""
        ts = [0.0]
        for a, b in _segments(t_end, self.leader.breakpoints, self.opts.chunk):
            ts.extend((a + (b - a) * np.linspace(0.0, 1.0, self.k + 1)[1:]).tolist())
        return np.asarray(ts)

    def _run_cascade(self, x0: np.ndarray, t_end: float, progress: ProgressFn | None) -> SimulationResult:
        """Integrate vehicle by vehicle in compiled code; stop everything at the first event."""
        n, nx, nq = self.n, self._nx, self._nq
        ncol = nx + nq + 3
        ts = self._sample_times(t_end)
        K = ts.size
        stops = np.asarray(sorted({b for b in self.leader.breakpoints if 0.0 < b < t_end} | {t_end}), float)
        out = np.empty((n, K, ncol))
        nsamp, kind = np.zeros(n, np.int32), np.zeros(n, np.int32)
        ev_time, ev_val, stats = np.zeros(n), np.zeros(n), np.zeros((n, 3), np.int64)
        x0v = np.ascontiguousarray(x0.reshape(nx, n).T)
        rc = self._run_c(n, np.asarray(self._law_of, np.int32), x0v, stops.size, stops, K, ts, self.opts.rtol,
                         self.opts.atol, self.opts.max_num_steps, out, nsamp, kind, ev_time, ev_val, stats)
        if rc != 0:
            raise MemoryError("simulate: the cascade integrator ran out of memory")
        events: list[Event] = []
        hit = np.where(kind > 0)[0]
        keep = K
        if hit.size:
            i = int(hit[np.argmin(ev_time[hit])])  # first in time; ties -> the vehicle nearest the leader
            t_ev = float(ev_time[i])
            if kind[i] == 6:
                h = float(ev_val[i])
                events.append(Event("integration_failed", t_ev, i,
                                    f"the integrator failed at t = {t_ev:.4f} with gap h = {h:.3g}"
                                    + (" (near collision)" if h < 0.05 else "")))
            else:
                name, msg = _EVENT_KINDS[int(kind[i])]
                events.append(Event(name, t_ev, i, f"{msg} (value {ev_val[i]:.4g} at the step ending after "
                                                   f"t = {t_ev:.4f})"))
            keep = max(1, int(np.searchsorted(ts, t_ev, side="left")))
        out = out[:, :keep]
        if progress is not None:
            progress(float(ts[keep - 1]), t_end)
        tk = ts[:keep]
        Z = out.transpose(2, 0, 1).reshape(ncol * n, keep)  # row c·n + i = column c of vehicle i
        if keep not in self._leader_maps:  # the mapped leader speed is reused across runs
            self._leader_maps[keep] = self.leader.speed_function.map(keep)
        vl = np.asarray(self._leader_maps[keep](tk.reshape(1, -1))).reshape(1, -1)
        Y = np.vstack([Z[(nx + nq) * n:], vl])
        res = self._assemble(tk, Z[:nx * n], Z[nx * n:(nx + nq) * n], Y, events)
        res.solver_stats = [{"nsteps": int(s[0]), "nrejected": int(s[1]), "nfev": int(s[2])} for s in stats]
        res.meta["integrator"] = "cascade-dopri5"
        return res

    # ------------------------------------------------------------------ running
    def run(self, gaps0: Sequence[float], speeds0: Sequence[float], t_end: float, *,
            soc0: float | Sequence[float] | None = None, progress: ProgressFn | None = None) -> SimulationResult:
        """Integrate from the initial gaps/speeds (model units) over [0, t_end] (model time)."""
        n = self.n
        h0, v0 = np.asarray(gaps0, float).ravel(), np.asarray(speeds0, float).ravel()
        if h0.size != n or v0.size != n:
            raise ParameterError(f"simulate: gaps0 and speeds0 need {n} values (one per follower), "
                                 f"got {h0.size} and {v0.size}")
        if not np.all(np.isfinite(h0)) or np.any(h0 <= 0):
            i = int(np.argmin(np.where(np.isfinite(h0), h0, -np.inf)))
            raise ParameterError(f"simulate: initial gap of vehicle {i + 1} is {h0[i]!r}: must be > 0")
        if not np.all(np.isfinite(v0)) or np.any(v0 < 0):
            i = int(np.argmin(np.where(np.isfinite(v0), v0, -np.inf)))
            raise ParameterError(f"simulate: initial speed of vehicle {i + 1} is {v0[i]!r}: must be >= 0")
        if not (math.isfinite(t_end) and t_end > 0):
            raise ParameterError(f"simulate: t_end = {t_end!r} is not allowed: must be > 0")
        x0 = [h0, v0]
        if self.battery:
            s0 = np.broadcast_to(np.asarray(self.ev.cell.soc0 if soc0 is None else soc0, float), (n,))
            x0 += [np.zeros(n), np.zeros(n), np.array(s0)]
        x = np.concatenate(x0)
        if self.method == "cascade":
            return self._run_cascade(x, t_end, progress)
        nq = self.integrator.size1_out("qf")
        q = np.zeros(nq)
        ts, xs, qs, ys = [np.array([0.0])], [x[:, None]], [q[:, None]], []
        events: list[Event] = []
        y0 = np.asarray(self.samples(np.zeros(self.k + 1), np.repeat(x[:, None], self.k + 1, axis=1)))[:, :1]
        ys.append(y0)
        ev0 = self._check(np.array([0.0]), x[:, None], y0)
        if ev0:
            events.append(ev0)
        else:
            for a, b in _segments(t_end, self.leader.breakpoints, self.opts.chunk):
                ok = self._advance(a, b, x, q, ts, xs, qs, ys, events, depth=0)
                x, q = xs[-1][:, -1], qs[-1][:, -1]
                if progress is not None:
                    progress(min(b, ts[-1][-1]), t_end)
                if not ok:
                    break
        return self._assemble(np.concatenate(ts), np.hstack(xs), np.hstack(qs), np.hstack(ys), events)

    def _advance(self, a: float, b: float, x: np.ndarray, q: np.ndarray, ts: list, xs: list, qs: list,
                 ys: list, events: list[Event], depth: int) -> bool:
        """Integrate [a, b] from (x, q); on a solver failure, subdivide to locate it. False = stop."""
        try:
            out = self.integrator(x0=x, p=[a, b - a])
        except RuntimeError as exc:
            if depth < 3:
                for lo, hi in zip(np.linspace(a, b, 11)[:-1], np.linspace(a, b, 11)[1:]):
                    if not self._advance(float(lo), float(hi), xs[-1][:, -1], qs[-1][:, -1], ts, xs, qs, ys,
                                         events, depth + 1):
                        return False
                return True
            h = x[: self.n]
            i = int(np.argmin(h))
            near = " (near collision)" if h[i] < 0.05 else ""
            events.append(Event("integration_failed", a, i, f"CVODES failed on [{a:.4f}, {b:.4f}] with gap "
                                f"h = {h[i]:.3g}{near} (CasADi: {str(exc).splitlines()[0][:120]})"))
            return False
        tk = a + (b - a) * np.linspace(0.0, 1.0, self.k + 1)[1:]
        xk = np.asarray(out["xf"])
        qk = q[:, None] + np.asarray(out["qf"])
        yk = np.asarray(self.samples(np.append(tk, tk[-1]), np.hstack([xk, xk[:, -1:]])))[:, :-1]
        prev = (ts[-1][-1], xs[-1][:, -1:], ys[-1][:, -1:])
        event = self._check(tk, xk, yk, prev)
        if event is not None:
            keep = tk < event.time
            ts.append(tk[keep]); xs.append(xk[:, keep]); qs.append(qk[:, keep]); ys.append(yk[:, keep])
            events.append(event)
            return False
        ts.append(tk); xs.append(xk); qs.append(qk); ys.append(yk)
        return True

    def _check(self, tk: np.ndarray, xk: np.ndarray, yk: np.ndarray,
               prev: tuple[float, np.ndarray, np.ndarray] | None = None) -> Event | None:
        """First violation among the samples, with its time interpolated from the previous sample."""
        n = self.n
        # the previous sample (for an event at the first sample of this chunk)
        xp, yp = (prev[1][:, 0], prev[2][:, 0]) if prev is not None else (None, None)
        rows = {"h": (xk[:n], None if xp is None else xp[:n]),
                "v": (xk[n:2 * n], None if xp is None else xp[n:2 * n])}
        checks = [("collision", "h", 1.0, 0.0, "gap h reached 0"),
                  ("negative_speed", "v", 1.0, -1e-9, "speed became negative")]
        if self.battery:
            rows["disc"] = (yk[2 * n:3 * n], None if yp is None else yp[2 * n:3 * n])
            rows["S"] = (xk[4 * n:5 * n], None if xp is None else xp[4 * n:5 * n])
            checks += [("infeasible_current", "disc", 1.0, 0.0, "cell cannot deliver the power demand (E² < 4 R_s P_c)"),
                       ("soc_out_of_range", "S", 1.0, 0.0, "state of charge fell below 0"),
                       ("soc_out_of_range", "S", -1.0, -1.0, "state of charge rose above 1")]
        first: Event | None = None
        for kind, key, sign, floor, msg in checks:
            cur, before = rows[key]
            arr = sign * cur - floor  # the quantity that must stay > 0 (collision) or >= 0 (others)
            bad = arr <= 0 if kind == "collision" else arr < 0
            if not bad.any():
                continue
            j = int(np.where(bad.any(axis=0))[0][0])
            i = int(np.where(bad[:, j])[0][0])
            t_ev = float(tk[j])
            # linear interpolation of the crossing between the previous sample and this one
            a0 = (sign * cur[i, j - 1] - floor) if j > 0 else (None if before is None else sign * before[i] - floor)
            if a0 is not None and a0 > 0:
                t_prev = float(tk[j - 1]) if j > 0 else prev[0]
                t_ev = t_prev + (t_ev - t_prev) * a0 / (a0 - arr[i, j])
            if first is None or t_ev < first.time:
                first = Event(kind, t_ev, i, f"{msg} (value {cur[i, j]:.4g} at t = {tk[j]:.4f})")
        return first

    def _assemble(self, t: np.ndarray, X: np.ndarray, Qc: np.ndarray, Y: np.ndarray,
                  events: list[Event]) -> SimulationResult:
        n, K = self.n, t.size
        nan = np.full((K, n), np.nan)
        rows = lambda M, j: M[j * n:(j + 1) * n].T  # noqa: E731
        bat = self.battery
        return SimulationResult(
            t=t, leader_speed=Y[3 * n], leader_position=np.asarray(self.leader.position(t), float),
            gap=rows(X, 0), speed=rows(X, 1), accel=rows(Y, 0),
            V1=rows(X, 2) if bat else nan, V2=rows(X, 3) if bat else nan, S=rows(X, 4) if bat else nan,
            current_A=rows(Y, 1) if bat else nan,
            omega=rows(Qc, 0), int_ovm_err2=rows(Qc, 1), int_rel_speed2=rows(Qc, 2), int_jerk2=rows(Qc, 3),
            heat_J=rows(Qc, 4) if bat else nan, heat_irr_J=rows(Qc, 5) if bat else nan,
            controllers=[law.name for law in self.laws], ev=self.ev, events=events,
            solver_stats=[None] * n,
            meta={"integrator": "cvodes", "rtol": self.opts.rtol, "atol": self.opts.atol,
                  "dt_out": self.opts.dt_out, "leader": self.leader.describe(),
                  "laws": [law.describe() for law in self.laws]})


def simulate_platoon(leader: LeaderProfile, laws: Sequence[CarFollowingLaw], gaps0: Sequence[float],
                     speeds0: Sequence[float], t_end: float, *, ev: EVParams | None = None,
                     soc0: float | Sequence[float] | None = None, dt_out: float = 0.01, rtol: float = 1e-10,
                     atol: float = 1e-10, battery: bool = True, progress: ProgressFn | None = None,
                     method: str = "auto") -> SimulationResult:
    """Simulate followers behind ``leader`` (model units) over [0, t_end]; see :class:`PlatoonSimulator`.
    method: "auto" (compiled cascade when a C compiler works, else CVODES), "cascade" or "cvodes"."""
    sim = PlatoonSimulator(leader, laws, ev, SimOptions(dt_out=dt_out, rtol=rtol, atol=atol, method=method),
                           battery=battery)
    return sim.run(gaps0, speeds0, t_end, soc0=soc0, progress=progress)
