/* ---------------- aev_ocp ring driver ----------------
 * Compiled after the CasADi-generated right-hand sides and a generated prologue (aev_ocp.ring.simulate):
 * SZ_ARG/SZ_RES/SZ_IW/SZ_W (work sizes), NX (ODE states per vehicle), NQ (quadratures), NY (outputs),
 * NCTRL (states in the error norm: h, v and the actuator state when there is one), AEV_NP (runtime coefficients per vehicle),
 * AEV_MOT_SWITCH and AEV_COEF_SWITCH (the case lists of the laws' motions and of their coefficient parts; AEV_LAW_SWITCH
 * is empty: dopri5.h's aev_law is not called here), the event table of aev_ocp.plant.EVENT_RULES, AEV_OCV_CALLS (the OCV
 * arguments of aevring_bat) and the cell's OCV table (ocv_lookup.h).
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
 * Memory traffic: each motion stage is ONE pass over the ring (a vehicle's stage state lives in registers; the
 * predecessor's stage speed is recomputed where it is read, with the same arithmetic, instead of stored by a separate
 * pass; the error of the last stage is summed in the same pass), and an accepted step's six battery stages are done
 * vehicle by vehicle (they couple no vehicles), so an accepted step sweeps the ring 7 times instead of 25.
 * The library is built with floating-point contraction off (aev_ocp.compiled.exact_tuned_flags): the same bits as
 * the plain build on any CPU (tests/test_compiled_speed.py).
 * With OpenMP (compiled with -fopenmp) the stage loops run on all cores (each thread its own CasADi work).
 * Events are checked after every accepted step on every vehicle and located on the quartic dense output
 * (bisection), the earliest over the ring wins.                                                        */
#include "dopri5.h"  /* NZ, aev_ctx, the Dormand-Prince tableau, aev_law, aev_dense_coef, aev_dense, aev_root */
#include "ocv_lookup.h"  /* aev_ocv: the cell's OCV(S), the same numbers as the model's piecewise cubic */
#ifdef _OPENMP
#include <omp.h>
#endif

static int ring_threads = 1;

/* A loop over the ring's vehicles: on ring_threads cores when there are many (OpenMP), each thread with its own
 * CasADi work (RING_CTX(ctx): this thread's). */
#ifdef _OPENMP
#define RING_PARALLEL _Pragma("omp parallel for schedule(static) num_threads(ring_threads) if (n >= 256 && ring_threads > 1)")
#define RING_CTX(ctx) ((ctx) + omp_get_thread_num())
#else
#define RING_PARALLEL
#define RING_CTX(ctx) (ctx)
#endif

/* The split right-hand side: the motion (h, v[, a_act]) of every law, which alone sets the step (the error norm), and
 * the battery and quadratures (one function for every law, from w = (h, v, v_l, a) of the motion and the cell
 * states), evaluated only once a step is accepted: a rejected step costs the motion alone, ~10 % of the whole. */
static const int MOT_IDX[NCTRL] = MOT_IDX_INIT;
static const int BAT_IDX[NB] = BAT_IDX_INIT;
static const int BAT_READ_IDX[NBR] = BAT_READ_IDX_INIT;

/* the motion of law ``law``: u = (v_l, noise), x the vehicle's state, q its law's coefficients (ring_coef) -> its
 * motion rates dm and w = (h, v, v_l, a) */
static int ring_mot(aev_ctx* c, int law, const double* q, const double* u, const double* x, double* dm, double* w) {
  c->arg[0] = u; c->arg[1] = x; c->arg[2] = q; c->res[0] = dm; c->res[1] = w;
  switch (law) {
AEV_MOT_SWITCH
  }
  return 1;
}

/* the coefficients q (AEV_NQ) of law ``law``'s motion from the vehicle's runtime coefficients par (AEV_NP): the parts of
 * the motion that depend on them alone (aev_ocp.ring.simulate: RingSimulator._motion_functions), once per advance */
static int ring_coef(aev_ctx* c, int law, const double* par, double* q) {
  c->arg[0] = par; c->res[0] = q;
  switch (law) {
AEV_COEF_SWITCH
  }
  return 1;
}

/* The OCV of each of the AEV_OCV_CALLS arguments S[j] into E[j] (aev_ocv); exported for tests/test_ring_ocv.py. */
CASADI_SYMBOL_EXPORT void aevring_ocv(int64_t m, const double* S, double* E) {
  for (int64_t j = 0; j < m; j++) E[j] = aev_ocv(S[j]);
}

/* The battery and quadrature rates db (NB: V1, V2, S and the quadratures) and the outputs y (a, I, disc) of one
 * vehicle from w = (h, v, v_l, a) of its motion and its state x. The model's OCV(S) is an input of aevring_bat:
 * aevring_bat_ocv gives its arguments S (the clamped SOC), aev_ocv their values. */
static void ring_bat(aev_ctx* c, const double* w, const double* x, double* db, double* y) {
  double S[AEV_OCV_CALLS], E[AEV_OCV_CALLS];
  c->arg[0] = w; c->arg[1] = x; c->res[0] = S;
  aevring_bat_ocv(c->arg, c->res, c->iw, c->w, 0);
  for (int j = 0; j < AEV_OCV_CALLS; j++) E[j] = aev_ocv(S[j]);
  c->arg[2] = E; c->res[0] = db; c->res[1] = y;
  aevring_bat(c->arg, c->res, c->iw, c->w, 0);
}

/* every vehicle's whole right-hand side at Z (n x NZ, vehicle-major) into D (n x NZ), outputs into Y when given;
 * u = (v_l, noise): its predecessor's speed and its additive acceleration noise. The motion and the battery as in a
 * step (ring_mot, ring_bat): the same numbers as the law's whole right-hand side (aevring_law, which the CVODES path
 * evaluates), with the OCV looked up. */
static void ring_rates(aev_ctx* ctx, int n, const int* law_idx, const double* q, const double* noise,
                       const double* Z, double* D, double* Y) {
  RING_PARALLEL
  for (int i = 0; i < n; i++) {
    aev_ctx* c = RING_CTX(ctx);
    double u[2], ybuf[NY], dm[NCTRL], w[4], db[NB];
    const double* x = Z + (int64_t)i * NZ;
    double* d = D + (int64_t)i * NZ;
    int p = i == 0 ? n - 1 : i - 1;
    u[0] = Z[(int64_t)p * NZ + 1]; u[1] = noise[i];
    ring_mot(c, law_idx[i], q + (int64_t)i * AEV_NQ, u, x, dm, w);
    ring_bat(c, w, x, db, Y ? Y + (int64_t)i * NY : ybuf);
    for (int jj = 0; jj < NCTRL; jj++) d[MOT_IDX[jj]] = dm[jj];
    for (int jj = 0; jj < NB; jj++) d[BAT_IDX[jj]] = db[jj];
  }
}

/* one entry of a stage state, z + h sum_{l < ns} coef[l] k[l], at the flat index j (vehicle-major): the one place
 * it is computed, so a vehicle's own stage and its follower's reading of it are the same number. Called with a
 * literal stage (RING_STAGES below), so the coefficients are constants and the sum is unrolled (in the same order). */
#define RING_INLINE static inline __attribute__((always_inline))
RING_INLINE double ring_stage_entry(const double* z, double* const* k, int st, double h, int64_t j) {
  const double* coef = st < 6 ? DP_A[st] : DP_B;
  int ns = st < 6 ? st : 6;
  double acc = 0; for (int l = 0; l < ns; l++) acc += coef[l] * k[l][j];
  return z[j] + h * acc;
}

/* Motion stage st (1..6) of vehicle i: its stage state (its motion entries), its predecessor's speed at the same
 * stage (recomputed where it is read: a few multiply-adds instead of a second pass over the ring and a stored
 * stage), its motion rates into k[st] and w into W. Stage 6 is the step's end: its motion entries go to zn, and the
 * vehicle's squared scaled error (the error norm's sum over h, v[, a_act]) to err[i] (the norm itself is reduced
 * in vehicle order by the caller). The motion reads only its own entries of x (MOT_IDX); the others stay 0. */
RING_INLINE void ring_motion_vehicle(aev_ctx* c, int st, int i, int n, const int* law_idx, const double* q,
                                     const double* noise, const double* z, double* const* k, double h, double* zn,
                                     double* W, double* err, double rtol, double atol) {
  double x[NZ] = {0}, u[2], dm[NCTRL];
  int p = i == 0 ? n - 1 : i - 1;
  for (int jj = 0; jj < NCTRL; jj++) x[MOT_IDX[jj]] = ring_stage_entry(z, k, st, h, (int64_t)i * NZ + MOT_IDX[jj]);
  u[0] = ring_stage_entry(z, k, st, h, (int64_t)p * NZ + 1); u[1] = noise[i];
  ring_mot(c, law_idx[i], q + (int64_t)i * AEV_NQ, u, x, dm, W + ((int64_t)st * n + i) * 4);
  for (int jj = 0; jj < NCTRL; jj++) k[st][(int64_t)i * NZ + MOT_IDX[jj]] = dm[jj];
  if (st == 6) {
    double* zni = zn + (int64_t)i * NZ;
    double e2 = 0;
    for (int jj = 0; jj < NCTRL; jj++) {
      int j = MOT_IDX[jj];  /* h, v and the actuator state (last of x) when there is one */
      int64_t jz = (int64_t)i * NZ + j;
      zni[j] = x[j];
      double e = 0; for (int l = 0; l < 7; l++) e += DP_E[l] * k[l][jz];
      double sc = atol + rtol * fmax(fabs(z[jz]), fabs(zni[j]));
      e = h * e / sc; e2 += e * e;
    }
    err[i] = e2;
  }
}

/* one pass over the ring per motion stage (a function per literal stage: RING_PARALLEL's loop body then has its
 * coefficients as constants) */
#define RING_MOTION_PASS(ST)                                                                                          \
  static void ring_motion_##ST(aev_ctx* ctx, int n, const int* law_idx, const double* q, const double* noise,      \
                               const double* z, double* const* k, double h, double* zn, double* W, double* err,     \
                               double rtol, double atol) {                                                          \
    RING_PARALLEL                                                                                                   \
    for (int i = 0; i < n; i++)                                                                                     \
      ring_motion_vehicle(RING_CTX(ctx), ST, i, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);             \
  }
RING_MOTION_PASS(1)
RING_MOTION_PASS(2)
RING_MOTION_PASS(3)
RING_MOTION_PASS(4)
RING_MOTION_PASS(5)
RING_MOTION_PASS(6)

/* battery and quadrature stage st of vehicle i: its stage state into xs, their rates from w of the same stage into
 * k[st]; outputs (a, I, disc) into yi. Stages 1..5 compute only the entries the battery reads (BAT_READ_IDX: the cell
 * states; the quadratures' stage values are read by nothing), stage 6 (the step's end) all of them. */
RING_INLINE void ring_battery_stage(aev_ctx* c, int st, int i, int n, const double* z, double* const* k, double h,
                                    const double* W, double* xs, double* yi) {
  double db[NB];
  if (st == 6)
    for (int jj = 0; jj < NB; jj++) xs[BAT_IDX[jj]] = ring_stage_entry(z, k, st, h, (int64_t)i * NZ + BAT_IDX[jj]);
  else
    for (int jj = 0; jj < NBR; jj++) xs[BAT_READ_IDX[jj]] = ring_stage_entry(z, k, st, h, (int64_t)i * NZ + BAT_READ_IDX[jj]);
  ring_bat(c, W + ((int64_t)st * n + i) * 4, xs, db, yi);
  for (int jj = 0; jj < NB; jj++) k[st][(int64_t)i * NZ + BAT_IDX[jj]] = db[jj];
}

/* The battery and quadrature stages of an accepted step, one vehicle at a time (they couple no vehicles: each reads
 * its own stages and its motion's w of every stage, W): stages 1..6 of its cell states and quadratures and their
 * rates into k, stage 6 (the step's end) into zn and its outputs (a, I, disc) into Y. The battery reads only its
 * own entries of x (V1, V2, S); the others stay 0. */
static void ring_battery_stages(aev_ctx* ctx, int n, const double* z, double* const* k, double h, const double* W,
                                double* zn, double* Y) {
  RING_PARALLEL
  for (int i = 0; i < n; i++) {
    aev_ctx* c = RING_CTX(ctx);
    double x[NZ] = {0}, ybuf[NY];
    ring_battery_stage(c, 1, i, n, z, k, h, W, x, ybuf);
    ring_battery_stage(c, 2, i, n, z, k, h, W, x, ybuf);
    ring_battery_stage(c, 3, i, n, z, k, h, W, x, ybuf);
    ring_battery_stage(c, 4, i, n, z, k, h, W, x, ybuf);
    ring_battery_stage(c, 5, i, n, z, k, h, W, x, ybuf);
    ring_battery_stage(c, 6, i, n, z, k, h, W, zn + (int64_t)i * NZ, Y + (int64_t)i * NY);
  }
}

/* Set nonzero by another thread (Ctrl-C, SIGTERM or a passed --time-limit in the Python caller, as the cascade's
 * aevsim_cancel) to stop an advance between two steps: aevring_advance then returns -2 at once, z and out partial. */
CASADI_SYMBOL_EXPORT volatile int aevring_cancel = 0;

/* Advance the ring from t0 to t1 (model time) with a constant noise vector; samples at ts[0..K-1]
 * (in (t0, t1], increasing) into out (K x n x (NZ + NY)). z (n x NZ) in: the state at t0, out: the state at
 * t1 or at the event. h_io: step size in/out. ev (4): kind (0 none, codes of EVENT_RULES, 6 failed),
 * vehicle, time, value. stats (3): steps, rejected, rhs evaluations (added to). brake (n x 4, or NULL): the
 * braking-event counters (acceleration below brake_a held brake_hold, model units; see the loop). Returns the number of samples
 * written, -1 when out of memory, -2 when stopped through aevring_cancel. */
CASADI_SYMBOL_EXPORT int64_t aevring_advance(int n, const int* law_idx, const double* params, const double* noise,
    double* z, double t0, double t1, int64_t K, const double* ts, double* out, double rtol, double atol,
    int64_t max_steps, double* h_io, double* ev, int64_t* stats, int threads, double* brake, double brake_a,
    double brake_hold, double brake_from) {
  int nth = 1;
#ifdef _OPENMP
  nth = threads > 1 ? threads : 1;
#endif
  ring_threads = nth;
  int64_t N = (int64_t)n * NZ, ncol = NZ + NY;
  aev_ctx* ctx = malloc(sizeof(aev_ctx) * nth);
  double* buf = malloc(sizeof(double) * (N * 7 + N * 3 + N * 4 + (int64_t)n * NY * 2 + (int64_t)n * 4 * 7 + n + (int64_t)n * AEV_NQ));
  if (!ctx || !buf) { free(ctx); free(buf); return -1; }
  double* k[7];
  for (int s = 0; s < 7; s++) k[s] = buf + s * N;
  double *zt = buf + 7 * N, *zn = zt + N, *zs = zn + N, *Q = zs + N, *Y = Q + 4 * N, *Ys = Y + (int64_t)n * NY;
  double* W = Ys + (int64_t)n * NY;  /* w = (h, v, v_l, a) of every vehicle at stages 1..6 (7 x n x 4) */
  double* err = W + (int64_t)n * 4 * 7;  /* each vehicle's squared scaled error of the last attempt (n) */
  double* q = err + n;  /* each vehicle's motion coefficients (n x AEV_NQ), from its runtime coefficients params */
  for (int i = 0; i < n; i++) ring_coef(ctx, law_idx[i], params + (int64_t)i * AEV_NP, q + (int64_t)i * AEV_NQ);
  double (*Q4)[4] = (double (*)[4])Q;  /* the dense output's coefficients, 4 per entry (N x 4) */
  int64_t s_out = 0, nst = 0, nrej = 0, nfev = 0;
  int rejected_last = 0;
  double t = t0, h = *h_io > 0 ? *h_io : 1e-3, h_want = h;
  ev[0] = 0; ev[1] = -1; ev[2] = t0; ev[3] = 0;
  ring_rates(ctx, n, law_idx, q, noise, z, k[0], NULL); nfev++;
  int cancelled = 0;
  while (t < t1 && !ev[0]) {
    if (aevring_cancel) { cancelled = 1; break; }
    int hit = 0;
    h_want = h;
    if (t + h >= t1 - 1e-12 * (1 + fabs(t1))) { h = t1 - t; hit = 1; }
    /* the motion stages: one pass over the ring each */
    ring_motion_1(ctx, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);
    ring_motion_2(ctx, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);
    ring_motion_3(ctx, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);
    ring_motion_4(ctx, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);
    ring_motion_5(ctx, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);
    ring_motion_6(ctx, n, law_idx, q, noise, z, k, h, zn, W, err, rtol, atol);
    nfev += 6;
    /* error: max(RMS over the ring, the largest per-vehicle RMS / LOCAL_FACTOR), reduced in vehicle order */
    double nrm = 0, sum2 = 0;
    for (int i = 0; i < n; i++) {
      double e2 = err[i];
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
    ring_battery_stages(ctx, n, z, k, h, W, zn, Y);  /* accepted: the battery and quadratures on the motion's stages */
    int q_ready = 0;  /* the dense output's coefficients, computed only when a sample or an event needs them */
#define RING_NEED_Q() if (!q_ready) { aev_dense_coef(N, k, Q4); q_ready = 1; }
#if SPEED_FLOOR
    /* with the vehicle limits on, the brakes hold a stopped car (speed_cut): a step that crosses v = 0 ends a
     * hair below it (the cut switches inside the step); project it back onto v >= 0, an error below the step's */
    for (int i = 0; i < n; i++) if (zn[(int64_t)i * NZ + 1] < 0) zn[(int64_t)i * NZ + 1] = 0;
#endif
    /* events of aev_ocp.plant.EVENT_RULES at the step end, located on the dense output */
    double th_ev = 2; int kind = 0, who = -1; double val = 0;
    for (int i = 0; i < n; i++) {
      const double* zi = z + (int64_t)i * NZ; const double* zni = zn + (int64_t)i * NZ;
      const double (*Qi)[4] = Q4 + (int64_t)i * NZ; const double* yi = Y + (int64_t)i * NY;
      if (AEV_EV1_SIGN * zni[0] - AEV_EV1_OFFSET <= 0) { RING_NEED_Q(); double th = aev_root(zi, Qi, h, 0, AEV_EV1_SIGN, AEV_EV1_OFFSET); if (th < th_ev) { th_ev = th; kind = 1; who = i; val = zni[0]; } }
      if (AEV_EV2_SIGN * zni[1] - AEV_EV2_OFFSET < 0) { RING_NEED_Q(); double th = aev_root(zi, Qi, h, 1, AEV_EV2_SIGN, AEV_EV2_OFFSET); if (th < th_ev) { th_ev = th; kind = 2; who = i; val = zni[1]; } }
      if (AEV_EV3_SIGN * yi[2] - AEV_EV3_OFFSET < 0 && 1.0 < th_ev) { th_ev = 1.0; kind = 3; who = i; val = yi[2]; }
#if BATTERY
      if (AEV_EV4_SIGN * zni[4] - AEV_EV4_OFFSET < 0) { RING_NEED_Q(); double th = aev_root(zi, Qi, h, 4, AEV_EV4_SIGN, AEV_EV4_OFFSET); if (th < th_ev) { th_ev = th; kind = 4; who = i; val = zni[4]; } }
      if (AEV_EV5_SIGN * zni[4] - AEV_EV5_OFFSET < 0) { RING_NEED_Q(); double th = aev_root(zi, Qi, h, 4, AEV_EV5_SIGN, AEV_EV5_OFFSET); if (th < th_ev) { th_ev = th; kind = 5; who = i; val = zni[4]; } }
#endif
    }
    double tend = hit ? t1 : t + h;
    double tlim = kind ? t + th_ev * h : tend;
    while (s_out < K && (kind ? ts[s_out] < tlim : ts[s_out] <= tlim + 1e-12 * (1 + fabs(tlim)))) {
      double th = (ts[s_out] - t) / h;
      if (th > 1) th = 1;
      RING_NEED_Q();
      double* o = out + s_out * (int64_t)n * ncol;
      for (int i = 0; i < n; i++) aev_dense(z + (int64_t)i * NZ, Q4 + (int64_t)i * NZ, h, th, zs + (int64_t)i * NZ);
      ring_rates(ctx, n, law_idx, q, noise, zs, zt, Ys); nfev++;
      for (int i = 0; i < n; i++) {
        memcpy(o + (int64_t)i * ncol, zs + (int64_t)i * NZ, NZ * sizeof(double));
        memcpy(o + (int64_t)i * ncol + NZ, Ys + (int64_t)i * NY, NY * sizeof(double));
      }
      s_out++;
    }
    nst++;
    /* braking events on the integrator's own steps (not the output samples): per vehicle brake[4i..4i+3] =
     * (since: the step end at which a < brake_a began, or -1; counted; events; events beginning at >= brake_from) */
    if (brake) {
      double te = kind ? tlim : tend;
      for (int i = 0; i < n; i++) {
        double* b = brake + 4 * (int64_t)i;
        if (Y[(int64_t)i * NY] < brake_a) {
          if (b[0] < 0) { b[0] = te; b[1] = 0; }
          if (!b[1] && te - b[0] >= brake_hold * (1 - 1e-12)) { b[1] = 1; b[2] += 1; if (b[0] >= brake_from) b[3] += 1; }
        } else b[0] = -1;
      }
    }
    if (kind) {
      RING_NEED_Q();
      for (int i = 0; i < n; i++) aev_dense(z + (int64_t)i * NZ, Q4 + (int64_t)i * NZ, h, th_ev, zs + (int64_t)i * NZ);
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
  return cancelled ? -2 : s_out;
}
