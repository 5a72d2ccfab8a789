/* ---------------- aev_ocp cascade driver ----------------
 * Compiled after the CasADi-generated right-hand sides and a generated prologue (aev_ocp.simulate):
 * SZ_ARG/SZ_RES/SZ_IW/SZ_W (work sizes), NX/NQ/NY (state, quadrature and output sizes), BATTERY,
 * AEV_NP (runtime parameters per vehicle), AEV_LAW_SWITCH (the case list of the laws) and the event table
 * of aev_ocp.plant.EVENT_RULES (AEV_EVk_OFFSET, AEV_EV_FAILED).
 * Vehicle i depends only on vehicle i-1, so the platoon is integrated vehicle by vehicle with an
 * adaptive Dormand-Prince 5(4) method (coefficients as in Dormand & Prince 1980 / SciPy RK45, quartic
 * dense output). The predecessor's speed v_l(t) and acceleration a_l(t) are its own dense output.
 * All z = (x, quadratures) are in the error norm (like CVODES with quad_err_con), except the last AEV_NQ_OUT
 * quadratures (the battery energy ∫P_b dt): outputs only, integrated on the steps the others choose, so adding
 * them changes no step, state or other integral.                                                           */
#include "dopri5.h"
#ifndef AEV_NQ_OUT
#define AEV_NQ_OUT 0
#endif  /* NZ, aev_ctx, the Dormand-Prince tableau, aev_law, aev_dense_coef, aev_dense, aev_root */
#define NCOL (NZ + NY)

typedef struct { int64_t m, cap, cur; double *t0, *h, *v0, *q; } aev_traj;

/* The run's inputs that are not compiled in (set by aevsim_run, one copy per thread): the g split
 * A = (1/η + η)/2, B = (1/η − η)/2, and the leader's parameters (aevsim_leader's second input). */
static _Thread_local double aev_omega_a, aev_omega_b;
static _Thread_local const double* aev_leader_par;

static void aev_leader(aev_ctx* c, double t, double* u) {
  c->arg[0] = &t; c->arg[1] = aev_leader_par; c->res[0] = u;
  aevsim_leader(c->arg, c->res, c->iw, c->w, 0);
}

static int aev_push(aev_traj* p, double t0, double h, double v0, const double* q) {
  if (p->m == p->cap) {
    int64_t cap = p->cap ? 2 * p->cap : 1024;
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
  int64_t j = p->cur;
  while (j < p->m - 1 && t > p->t0[j] + p->h[j]) j++;
  while (j > 0 && t < p->t0[j]) j--;
  p->cur = j;
  double h = p->h[j], th = (t - p->t0[j]) / h;
  if (th < 0) th = 0;
  if (th > 1) th = 1;
  const double* q = p->q + 4 * j;
  u[0] = p->v0[j] + h * th * (q[0] + th * (q[1] + th * (q[2] + th * q[3])));
  u[1] = q[0] + th * (2 * q[1] + th * (3 * q[2] + th * 4 * q[3]));
}

static void aev_input(aev_ctx* c, aev_traj* prev, int i, double t, double* u) {
  if (i == 0) aev_leader(c, t, u); else aev_traj_eval(prev, t, u);
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
  return aev_omega_a * (we - 0.5 * v0 * v0) + aev_omega_b * tv;
}

/* the row (z, y, v_l) of a vehicle at theta in a step: dense z, exact omega, outputs of the law there */
static void aev_row(aev_ctx* c, aev_traj* prev, int i, int law, const double* par, const double* z,
                    const double (*Q)[4], double t, double h, double th, double* row) {
  double u[2], dz[NZ];
  aev_dense(z, Q, h, th, row);
  row[NX] = z[NX] + aev_omega_inc(z[1], Q[1], h, th);
  aev_input(c, prev, i, t + th * h, u); aev_law(c, law, par, u, row, dz, row + NZ);
  row[NCOL] = u[0];
}

/* Set nonzero by another thread (Ctrl-C or SIGTERM in the Python caller) to stop a run between two steps:
 * aevsim_run then returns 2 at once and its outputs are incomplete. */
CASADI_SYMBOL_EXPORT volatile int aevsim_cancel = 0;

/* The samples go to out column by column (NCOL x n x K, C order): entry c of vehicle i at sample s is
 * out[(c n + i) K + s], so the caller's (quantity, vehicle) x time table is out itself, without a transpose (a
 * transpose of the samples of 10 000 vehicles cost more than their integration). */
static void aev_put(double* out, int n, int i, int64_t K, int s, const double* row) {
  double* o = out + (int64_t)i * K + s;
  const int64_t stride = (int64_t)n * K;
  for (int c = 0; c < NCOL; c++) o[c * stride] = row[c];
}

/* Returns 0 on success, 1 on out-of-memory, 2 when stopped through aevsim_cancel. Event kinds: 0 none, 1 collision, 2 negative_speed,
 * 3 infeasible_current, 4 soc below 0, 5 soc above 1, 6 integration failed.
 * last (n x (NCOL + 1)): each vehicle's row (z, y, v_l) where its integration ended: at its event (on the
 * dense output, the rule firing there: a collision has h <= 0), else at its last step's end. */
CASADI_SYMBOL_EXPORT int aevsim_run(int n, const int* law_idx, const double* params, const double* x0, int nstop, const double* stops,
    int K, const double* ts, double rtol, double atol, int64_t max_steps,
    double* out, int* nsamp, int* ev_kind, double* ev_time, double* ev_val, int64_t* stats, double* last,
    const double* glob) {
  /* glob: (A, B) of the g split, then the leader's parameters */
  aev_omega_a = glob[0]; aev_omega_b = glob[1]; aev_leader_par = glob + 2;
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
    const double* par = params + (int64_t)i * AEV_NP;  /* the law's coefficients (runtime, not compiled in) */
    double z[NZ], zn[NZ], zt[NZ], k[7][NZ], Q[NZ][4], y[NY], yn[NY], u[2], tmp[NZ];
    double* const kp[7] = {k[0], k[1], k[2], k[3], k[4], k[5], k[6]};
    double o[NCOL];  /* one sample's row (z, y), stored with aev_put */
    int64_t nst = 0, nrej = 0, nfev = 0;
    int s = 0, kind = 0, istop = 0;
    double t = 0, tev = INFINITY, val = 0;
    for (int j = 0; j < NX; j++) z[j] = x0[i * NX + j];
    for (int j = NX; j < NZ; j++) z[j] = 0;
    if (i > 0 && prev->m == 0) {
      /* the predecessor stopped at t = 0 (an event or a failure before its first step): there is no
       * trajectory to follow; record the initial sample with its measured speed and stop here */
      u[0] = x0[(i - 1) * NX + 1]; u[1] = 0;
      aev_law(c, law, par, u, z, k[0], y);
      memcpy(o, z, NZ * sizeof(double)); memcpy(o + NZ, y, NY * sizeof(double)); aev_put(out, n, i, K, 0, o);
      memcpy(last + (int64_t)i * (NCOL + 1), o, NCOL * sizeof(double)); last[(int64_t)i * (NCOL + 1) + NCOL] = u[0];
      nsamp[i] = 1; ev_kind[i] = 0; ev_time[i] = 0; ev_val[i] = 0;
      stats[3 * i] = 0; stats[3 * i + 1] = 0; stats[3 * i + 2] = 1;
      continue;
    }
    aev_input(c, prev, i, t, u); aev_law(c, law, par, u, z, k[0], y); nfev++;
    /* sample at t = 0 and the initial check */
    memcpy(o, z, NZ * sizeof(double)); memcpy(o + NZ, y, NY * sizeof(double)); aev_put(out, n, i, K, 0, o); s = 1;
    if (AEV_EV3_SIGN * y[2] - AEV_EV3_OFFSET < 0) { kind = 3; tev = 0; val = y[2]; }
    if (BATTERY && AEV_EV4_SIGN * z[4] - AEV_EV4_OFFSET < 0) { kind = 4; tev = 0; val = z[4]; }
    if (BATTERY && AEV_EV5_SIGN * z[4] - AEV_EV5_OFFSET < 0) { kind = 5; tev = 0; val = z[4]; }
    double h = 1e-4;
    while (!kind && t < tmax) {
      if (aevsim_cancel) { status = 2; break; }
      while (istop < nstop - 1 && stops[istop] <= t) istop++;
      double tstop = stops[istop] < tmax ? stops[istop] : tmax;
      int hit = 0;
      if (t + h >= tstop - 1e-12 * (1 + fabs(tstop))) { h = tstop - t; hit = 1; }
      for (int st = 1; st < 6; st++) {
        for (int j = 0; j < NZ; j++) {
          double acc = 0; for (int l = 0; l < st; l++) acc += DP_A[st][l] * k[l][j];
          zt[j] = z[j] + h * acc;
        }
        aev_input(c, prev, i, t + DP_C[st] * h, u); aev_law(c, law, par, u, zt, k[st], tmp);
      }
      for (int j = 0; j < NZ; j++) {
        double acc = 0; for (int l = 0; l < 6; l++) acc += DP_B[l] * k[l][j];
        zn[j] = z[j] + h * acc;
      }
      aev_input(c, prev, i, t + h, u); aev_law(c, law, par, u, zn, k[6], yn); nfev += 6;
      double nrm = 0;
      for (int j = 0; j < NZ - AEV_NQ_OUT; j++) {
        if (j == NX) continue;  /* ω is computed exactly from v below */
#if AEV_JERK_UNCONTROLLED
        if (j == NX + 3) continue;  /* ∫jerk²: its integrand jumps where a vehicle limit starts or stops acting */
#endif
        double e = 0; for (int l = 0; l < 7; l++) e += DP_E[l] * k[l][j];
        double sc = atol + rtol * fmax(fabs(z[j]), fabs(zn[j]));
        e = h * e / sc; nrm += e * e;
      }
      nrm = sqrt(nrm / (NZ - 1 - AEV_JERK_UNCONTROLLED - AEV_NQ_OUT));
      if (!isfinite(nrm)) nrm = INFINITY;
      if (nrm > 1) {
        nrej++;
        h *= fmax(0.2, 0.9 * pow(nrm, -0.2));
        if (h < 1e-14 * (1 + fabs(t)) || nst + nrej > max_steps) { kind = AEV_EV_FAILED; tev = t; val = z[0]; }
        continue;
      }
      aev_dense_coef(NZ, kp, Q);
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
      /* the rules of aev_ocp.plant.EVENT_RULES: margin = sign * value - offset */
      if (AEV_EV1_SIGN * zn[0] - AEV_EV1_OFFSET <= 0) { double th = aev_root(z, Q, h, 0, AEV_EV1_SIGN, AEV_EV1_OFFSET); if (th < th_ev) { th_ev = th; kind = 1; val = zn[0]; } }
      if (AEV_EV2_SIGN * zn[1] - AEV_EV2_OFFSET < 0) { double th = aev_root(z, Q, h, 1, AEV_EV2_SIGN, AEV_EV2_OFFSET); if (th < th_ev) { th_ev = th; kind = 2; val = zn[1]; } }
      if (AEV_EV3_SIGN * yn[2] - AEV_EV3_OFFSET < 0) { double th = y[2] > 0 ? y[2] / (y[2] - yn[2]) : 0; if (th < th_ev) { th_ev = th; kind = 3; val = yn[2]; } }
      if (BATTERY && AEV_EV4_SIGN * zn[4] - AEV_EV4_OFFSET < 0) { double th = aev_root(z, Q, h, 4, AEV_EV4_SIGN, AEV_EV4_OFFSET); if (th < th_ev) { th_ev = th; kind = 4; val = zn[4]; } }
      if (BATTERY && AEV_EV5_SIGN * zn[4] - AEV_EV5_OFFSET < 0) { double th = aev_root(z, Q, h, 4, AEV_EV5_SIGN, AEV_EV5_OFFSET); if (th < th_ev) { th_ev = th; kind = 5; val = zn[4]; } }
      double tend = hit ? tstop : t + h;
      if (kind) tev = t + th_ev * h;
      double tlim = kind ? tev : tend;
      while (s < K && (kind ? ts[s] < tlim : ts[s] <= tlim + 1e-12 * (1 + fabs(tlim)))) {
        double th = (ts[s] - t) / h, us[2], dz[NZ];
        if (th > 1) th = 1;
        double* os = o;
        aev_dense(z, Q, h, th, os);
        os[NX] = z[NX] + aev_omega_inc(z[1], Q[1], h, th);
        aev_input(c, prev, i, ts[s], us); aev_law(c, law, par, us, os, dz, os + NZ); nfev++;
        aev_put(out, n, i, K, s, os);
        s++;
      }
      nst++;
      if (kind) { aev_row(c, prev, i, law, par, z, Q, t, h, th_ev, last + (int64_t)i * (NCOL + 1)); break; }
      t = tend;
      memcpy(z, zn, sizeof z); memcpy(y, yn, sizeof y); memcpy(k[0], k[6], sizeof k[0]);
      if (hit && t < tmax) {  /* restart at a breakpoint: the leader's acceleration may jump there */
        aev_input(c, prev, i, t, u); aev_law(c, law, par, u, z, k[0], y); nfev++;
      }
      h *= nrm == 0 ? 10 : fmin(10, 0.9 * pow(nrm, -0.2));
      if (nst + nrej > max_steps) { kind = AEV_EV_FAILED; tev = t; val = z[0]; }
    }
    if (kind == 0 || kind == AEV_EV_FAILED || (s == 1 && tev == 0)) {  /* ended at t (or failed/stopped at t = 0) */
      double* row = last + (int64_t)i * (NCOL + 1);
      memcpy(row, z, NZ * sizeof(double));
      aev_input(c, prev, i, t, u); aev_law(c, law, par, u, z, k[0], row + NZ); row[NCOL] = u[0];
    }
    nsamp[i] = s; ev_kind[i] = kind; ev_time[i] = kind ? tev : t; ev_val[i] = val;
    stats[3 * i] = nst; stats[3 * i + 1] = nrej; stats[3 * i + 2] = nfev;
    if (kind && tev < tmax) tmax = tev;
  }
  for (int j = 0; j < 2; j++) { free(tr[j].t0); free(tr[j].h); free(tr[j].v0); free(tr[j].q); }
  free(c);
  return status;
}
