/* ---------------- aev_ocp ring driver ----------------
 * Compiled after the CasADi-generated right-hand sides and a generated prologue (aev_ocp.ring.simulate):
 * SZ_ARG/SZ_RES/SZ_IW/SZ_W (work sizes), NX (ODE states per vehicle), NQ (quadratures), NY (outputs),
 * NCTRL (states in the error norm: h, v and the actuator state when there is one), AEV_NP (runtime coefficients per vehicle),
 * AEV_LAW_SWITCH (the case list of the laws) and the event table of aev_ocp.plant.EVENT_RULES.
 *
 * A ring closes the chain (vehicle 0 follows vehicle n-1), so the cascade's one-vehicle-at-a-time
 * integration does not apply without iterating. Here the whole ring is ONE explicit adaptive
 * Dormand-Prince 5(4) system (coefficients as in Dormand & Prince 1980 / SciPy RK45, FSAL): every stage is
 * one loop over the vehicles, each reading its predecessor's speed from the same stage, so the cost per step
 * is linear in n, and the ring's gap sum is conserved exactly (the gap rates sum to 0 at every stage).
 * The error norm is max(RMS over the whole ring, largest per-vehicle RMS / LOCAL_FACTOR) over the motion
 * states (h, v[, a_act]); with LOCAL_FACTOR = 1 (the default) no vehicle's error exceeds the tolerance, so a
 * wave in one vehicle of 10 000 is not averaged away; a larger factor lets one vehicle at a kink of its
 * right-hand side (a stop: the speed cut; a saturation) reach LOCAL_FACTOR × the tolerance while the ring's
 * RMS stays within it, which in big jammed rings (a kink somewhere in every step) saves most rejected steps. The cell states (V1, V2, S) and the quadratures (distance, energy, heat, ...)
 * ride along with the same weights but do not steer the step: they are driven by the motion through the power
 * map, their time constants (R1 C1 = 3.9 s, R2 C2 = 100 s) are far longer than the steps the motion needs, and
 * their rates kink at every sign change of the power (the eta switch), which in a ring of thousands of vehicles
 * happens every few milliseconds somewhere and would cost rejected steps without adding accuracy
 * (tests/test_ring.py compares them with CVODES, which controls them).
 * With OpenMP (compiled with -fopenmp) the stage loops run on all cores (each thread its own CasADi work).
 * Events are checked after every accepted step on every vehicle and located on the quartic dense output
 * (bisection), the earliest over the ring wins.                                                        */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#define NZ (NX + NQ)

typedef struct { const casadi_real* arg[SZ_ARG]; casadi_real* res[SZ_RES]; casadi_int iw[SZ_IW + 1]; casadi_real w[SZ_W + 1]; } ring_ctx;

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

static int ring_threads = 1;

static int ring_law(ring_ctx* c, int law, const double* par, const double* u, const double* x, double* dz, double* y) {
  c->arg[0] = u; c->arg[1] = x; c->arg[2] = par; c->res[0] = dz; c->res[1] = y;
  switch (law) {
AEV_LAW_SWITCH
  }
  return 1;
}

/* The split right-hand side: the motion (h, v[, a_act]) of every law, which alone sets the step (the error norm), and
 * the battery and quadratures (one function for every law, from w = (h, v, v_l, a) of the motion and the cell
 * states), evaluated only once a step is accepted: a rejected step costs the motion alone, ~10 % of the whole. */
static const int MOT_IDX[NCTRL] = MOT_IDX_INIT;
static const int BAT_IDX[NB] = BAT_IDX_INIT;

static int ring_mot(ring_ctx* c, int law, const double* par, const double* u, const double* x, double* dm, double* w) {
  c->arg[0] = u; c->arg[1] = x; c->arg[2] = par; c->res[0] = dm; c->res[1] = w;
  switch (law) {
AEV_MOT_SWITCH
  }
  return 1;
}

/* motion rates of every vehicle at Z into D's motion entries; w = (h, v, v_l, a) into W (n x 4) */
static void ring_motion(ring_ctx* ctx, int n, const int* law_idx, const double* params, const double* noise,
                        const double* Z, double* D, double* W) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(ring_threads) if (n >= 256 && ring_threads > 1)
#endif
  for (int i = 0; i < n; i++) {
#ifdef _OPENMP
    ring_ctx* c = ctx + omp_get_thread_num();
#else
    ring_ctx* c = ctx;
#endif
    double u[2], dm[NCTRL];
    int p = i == 0 ? n - 1 : i - 1;
    u[0] = Z[(int64_t)p * NZ + 1]; u[1] = noise[i];
    ring_mot(c, law_idx[i], params + (int64_t)i * AEV_NP, u, Z + (int64_t)i * NZ, dm, W + 4 * (int64_t)i);
    for (int j = 0; j < NCTRL; j++) D[(int64_t)i * NZ + MOT_IDX[j]] = dm[j];
  }
}

/* battery and quadrature rates of every vehicle at Z (its cell states) and W (its motion) into D's other entries;
 * outputs (a, I, disc) into Y when given */
static void ring_battery(ring_ctx* ctx, int n, const double* Z, const double* W, double* D, double* Y) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(ring_threads) if (n >= 256 && ring_threads > 1)
#endif
  for (int i = 0; i < n; i++) {
#ifdef _OPENMP
    ring_ctx* c = ctx + omp_get_thread_num();
#else
    ring_ctx* c = ctx;
#endif
    double db[NB], ybuf[NY];
    c->arg[0] = W + 4 * (int64_t)i; c->arg[1] = Z + (int64_t)i * NZ; c->res[0] = db; c->res[1] = Y ? Y + (int64_t)i * NY : ybuf;
    aevring_bat(c->arg, c->res, c->iw, c->w, 0);
    for (int j = 0; j < NB; j++) D[(int64_t)i * NZ + BAT_IDX[j]] = db[j];
  }
}

/* z + h sum_l coef[l] k[l] on the given entries of every vehicle (idx: cnt entries per vehicle) into dst */
static void ring_stage(int n, const int* idx, int cnt, const double* z, double* const* k, const double* coef, int ns,
                       double h, double* dst) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(ring_threads) if (n >= 256 && ring_threads > 1)
#endif
  for (int i = 0; i < n; i++)
    for (int jj = 0; jj < cnt; jj++) {
      int64_t j = (int64_t)i * NZ + idx[jj];
      double acc = 0; for (int l = 0; l < ns; l++) acc += coef[l] * k[l][j];
      dst[j] = z[j] + h * acc;
    }
}

/* the ring's right-hand side at state Z (n x NZ, vehicle-major) into D (n x NZ); outputs into Y when given.
 * u = (v_l, noise): the predecessor's speed and the vehicle's additive acceleration noise. */
static void ring_rhs(ring_ctx* ctx, int n, const int* law_idx, const double* params, const double* noise,
                     const double* Z, double* D, double* Y) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(ring_threads) if (n >= 256 && ring_threads > 1)
#endif
  for (int i = 0; i < n; i++) {
#ifdef _OPENMP
    ring_ctx* c = ctx + omp_get_thread_num();
#else
    ring_ctx* c = ctx;
#endif
    double u[2], ybuf[NY];
    int p = i == 0 ? n - 1 : i - 1;
    u[0] = Z[(int64_t)p * NZ + 1]; u[1] = noise[i];
    ring_law(c, law_idx[i], params + (int64_t)i * AEV_NP, u, Z + (int64_t)i * NZ, D + (int64_t)i * NZ,
             Y ? Y + (int64_t)i * NY : ybuf);
  }
}

static void ring_dense_coef(int64_t N, double* const* k, double* Q) {
  for (int64_t j = 0; j < N; j++)
    for (int m = 0; m < 4; m++) {
      double acc = 0; for (int l = 0; l < 7; l++) acc += k[l][j] * DP_P[l][m];
      Q[4 * j + m] = acc;
    }
}

static void ring_dense1(const double* z, const double* Q, double h, double th, double* out) {
  for (int k = 0; k < NZ; k++)
    out[k] = z[k] + h * th * (Q[4 * k] + th * (Q[4 * k + 1] + th * (Q[4 * k + 2] + th * Q[4 * k + 3])));
}

/* first theta in (0, 1] where state k of vehicle i (dense output), as sign*value - off, becomes <= 0 */
static double ring_root(const double* z, const double* Q, double h, int k, double sign, double off) {
  double lo = 0, hi = 1, buf[NZ];
  for (int it = 0; it < 60; it++) {
    double mid = 0.5 * (lo + hi);
    ring_dense1(z, Q, h, mid, buf);
    if (sign * buf[k] - off > 0) lo = mid; else hi = mid;
  }
  return hi;
}

/* Advance the ring from t0 to t1 (model time) with a constant noise vector; samples at ts[0..K-1]
 * (in (t0, t1], increasing) into out (K x n x (NZ + NY)). z (n x NZ) in: the state at t0, out: the state at
 * t1 or at the event. h_io: step size in/out. ev (4): kind (0 none, codes of EVENT_RULES, 6 failed),
 * vehicle, time, value. stats (3): steps, rejected, rhs evaluations (added to). Returns the number of samples
 * written, or -1 when out of memory. */
CASADI_SYMBOL_EXPORT int64_t aevring_advance(int n, const int* law_idx, const double* params, const double* noise,
    double* z, double t0, double t1, int64_t K, const double* ts, double* out, double rtol, double atol,
    int64_t max_steps, double* h_io, double* ev, int64_t* stats, int threads) {
  int nth = 1;
#ifdef _OPENMP
  nth = threads > 1 ? threads : 1;
#endif
  ring_threads = nth;
  int64_t N = (int64_t)n * NZ, ncol = NZ + NY;
  ring_ctx* ctx = malloc(sizeof(ring_ctx) * nth);
  double* buf = malloc(sizeof(double) * (N * 7 + N * 3 + N * 4 + (int64_t)n * NY * 2 + (int64_t)n * 4 * 7));
  if (!ctx || !buf) { free(ctx); free(buf); return -1; }
  double* k[7];
  for (int s = 0; s < 7; s++) k[s] = buf + s * N;
  double *zt = buf + 7 * N, *zn = zt + N, *zs = zn + N, *Q = zs + N, *Y = Q + 4 * N, *Ys = Y + (int64_t)n * NY;
  double* W = Ys + (int64_t)n * NY;  /* w = (h, v, v_l, a) of every vehicle at stages 1..6 (7 x n x 4) */
  int64_t s_out = 0, nst = 0, nrej = 0, nfev = 0;
  int rejected_last = 0;
  double t = t0, h = *h_io > 0 ? *h_io : 1e-3, h_want = h;
  ev[0] = 0; ev[1] = -1; ev[2] = t0; ev[3] = 0;
  ring_rhs(ctx, n, law_idx, params, noise, z, k[0], NULL); nfev++;
  while (t < t1 && !ev[0]) {
    int hit = 0;
    h_want = h;
    if (t + h >= t1 - 1e-12 * (1 + fabs(t1))) { h = t1 - t; hit = 1; }
    for (int st = 1; st < 7; st++) {  /* the motion stages */
      ring_stage(n, MOT_IDX, NCTRL, z, k, st < 6 ? DP_A[st] : DP_B, st < 6 ? st : 6, h, st < 6 ? zt : zn);
      ring_motion(ctx, n, law_idx, params, noise, st < 6 ? zt : zn, k[st], W + (int64_t)st * n * 4);
    }
    nfev += 6;
    /* error: the largest per-vehicle RMS over the ODE states */
    double nrm = 0, sum2 = 0;
    for (int i = 0; i < n; i++) {
      double e2 = 0;
      for (int jj = 0; jj < NCTRL; jj++) {
        int j = jj < 2 ? jj : NX - 1;  /* h, v and the actuator state (last of x) when there is one */
        int64_t q = (int64_t)i * NZ + j;
        double e = 0; for (int l = 0; l < 7; l++) e += DP_E[l] * k[l][q];
        double sc = atol + rtol * fmax(fabs(z[q]), fabs(zn[q]));
        e = h * e / sc; e2 += e * e;
      }
      sum2 += e2;
      e2 = sqrt(e2 / NCTRL) / LOCAL_FACTOR;
      if (!(e2 <= nrm)) nrm = e2;  /* NaN propagates as a failure */
    }
    { double r = sqrt(sum2 / ((double)n * NCTRL)); if (!(r <= nrm)) nrm = r; }
    if (!isfinite(nrm)) nrm = INFINITY;
    if (nrm > 1) {
      nrej++; rejected_last = 1;
      h *= fmax(0.2, 0.9 * pow(nrm, -0.2));
      if (h < 1e-14 * (1 + fabs(t)) || nst + nrej > max_steps) { ev[0] = AEV_EV_FAILED; ev[1] = -1; ev[2] = t; }
      continue;
    }
    for (int st = 1; st < 7; st++) {  /* accepted: the battery and quadrature stages on the motion's stages */
      ring_stage(n, BAT_IDX, NB, z, k, st < 6 ? DP_A[st] : DP_B, st < 6 ? st : 6, h, st < 6 ? zt : zn);
      ring_battery(ctx, n, st < 6 ? zt : zn, W + (int64_t)st * n * 4, k[st], st == 6 ? Y : NULL);
    }
    int q_ready = 0;  /* the dense output's coefficients, computed only when a sample or an event needs them */
#define RING_NEED_Q() if (!q_ready) { ring_dense_coef(N, k, Q); q_ready = 1; }
#if SPEED_FLOOR
    /* with the vehicle limits on, the brakes hold a stopped car (speed_cut): a step that crosses v = 0 ends a
     * hair below it (the cut switches inside the step); project it back onto v >= 0, an error below the step's */
    for (int i = 0; i < n; i++) if (zn[(int64_t)i * NZ + 1] < 0) zn[(int64_t)i * NZ + 1] = 0;
#endif
    /* events of aev_ocp.plant.EVENT_RULES at the step end, located on the dense output */
    double th_ev = 2; int kind = 0, who = -1; double val = 0;
    for (int i = 0; i < n; i++) {
      const double* zi = z + (int64_t)i * NZ; const double* zni = zn + (int64_t)i * NZ;
      const double* Qi = Q + 4 * (int64_t)i * NZ; const double* yi = Y + (int64_t)i * NY;
      if (AEV_EV1_SIGN * zni[0] - AEV_EV1_OFFSET <= 0) { RING_NEED_Q(); double th = ring_root(zi, Qi, h, 0, AEV_EV1_SIGN, AEV_EV1_OFFSET); if (th < th_ev) { th_ev = th; kind = 1; who = i; val = zni[0]; } }
      if (AEV_EV2_SIGN * zni[1] - AEV_EV2_OFFSET < 0) { RING_NEED_Q(); double th = ring_root(zi, Qi, h, 1, AEV_EV2_SIGN, AEV_EV2_OFFSET); if (th < th_ev) { th_ev = th; kind = 2; who = i; val = zni[1]; } }
      if (AEV_EV3_SIGN * yi[2] - AEV_EV3_OFFSET < 0 && 1.0 < th_ev) { th_ev = 1.0; kind = 3; who = i; val = yi[2]; }
#if BATTERY
      if (AEV_EV4_SIGN * zni[4] - AEV_EV4_OFFSET < 0) { RING_NEED_Q(); double th = ring_root(zi, Qi, h, 4, AEV_EV4_SIGN, AEV_EV4_OFFSET); if (th < th_ev) { th_ev = th; kind = 4; who = i; val = zni[4]; } }
      if (AEV_EV5_SIGN * zni[4] - AEV_EV5_OFFSET < 0) { RING_NEED_Q(); double th = ring_root(zi, Qi, h, 4, AEV_EV5_SIGN, AEV_EV5_OFFSET); if (th < th_ev) { th_ev = th; kind = 5; who = i; val = zni[4]; } }
#endif
    }
    double tend = hit ? t1 : t + h;
    double tlim = kind ? t + th_ev * h : tend;
    while (s_out < K && (kind ? ts[s_out] < tlim : ts[s_out] <= tlim + 1e-12 * (1 + fabs(tlim)))) {
      double th = (ts[s_out] - t) / h;
      if (th > 1) th = 1;
      RING_NEED_Q();
      double* o = out + s_out * (int64_t)n * ncol;
      for (int i = 0; i < n; i++) ring_dense1(z + (int64_t)i * NZ, Q + 4 * (int64_t)i * NZ, h, th, zs + (int64_t)i * NZ);
      ring_rhs(ctx, n, law_idx, params, noise, zs, zt, Ys); nfev++;
      for (int i = 0; i < n; i++) {
        memcpy(o + (int64_t)i * ncol, zs + (int64_t)i * NZ, NZ * sizeof(double));
        memcpy(o + (int64_t)i * ncol + NZ, Ys + (int64_t)i * NY, NY * sizeof(double));
      }
      s_out++;
    }
    nst++;
    if (kind) {
      RING_NEED_Q();
      for (int i = 0; i < n; i++) ring_dense1(z + (int64_t)i * NZ, Q + 4 * (int64_t)i * NZ, h, th_ev, zs + (int64_t)i * NZ);
      memcpy(z, zs, N * sizeof(double));
      ev[0] = kind; ev[1] = who; ev[2] = tlim; ev[3] = val;
      break;
    }
    t = tend;
    memcpy(z, zn, N * sizeof(double)); memcpy(k[0], k[6], N * sizeof(double));
    /* no growth right after a rejection (Hairer, Nørsett & Wanner, Solving ODEs I, §II.4): it only repeats it */
    h *= rejected_last ? fmin(1, 0.9 * pow(fmax(nrm, 1e-10), -0.2)) : (nrm == 0 ? 10 : fmin(10, 0.9 * pow(nrm, -0.2)));
    rejected_last = 0;
    if (hit) h_want = fmax(h_want, h);
    if (nst + nrej > max_steps) { ev[0] = AEV_EV_FAILED; ev[1] = -1; ev[2] = t; }
  }
  if (!ev[0]) *h_io = h_want;
  stats[0] += nst; stats[1] += nrej; stats[2] += nfev;
  free(ctx); free(buf);
  return s_out;
}
