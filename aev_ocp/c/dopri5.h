/* ---------------- aev_ocp: what the cascade and ring drivers share ----------------
 * Included by cascade.c and ring.c (aev_ocp.compiled.driver_source inlines it, so the compiled library's cache
 * key covers it). Needs NX, NQ, SZ_ARG, SZ_RES, SZ_IW, SZ_W and AEV_LAW_SWITCH from the generated prologue.
 * The Dormand-Prince 5(4) tableau (Dormand & Prince 1980, as in SciPy's RK45) with the quartic dense output
 * (Shampine 1986, SciPy's P matrix), the CasADi work of one evaluation, the dispatch to a vehicle's law, and the
 * dense output with the bisection that locates an event on it. */
#ifndef AEV_DOPRI5_H
#define AEV_DOPRI5_H
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#define NZ (NX + NQ)

typedef struct { const casadi_real* arg[SZ_ARG]; casadi_real* res[SZ_RES]; casadi_int iw[SZ_IW + 1]; casadi_real w[SZ_W + 1]; } aev_ctx;

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

/* the law ``law`` of a vehicle: u = (v_l, a_l or noise), x its state, par its coefficients -> dz, y */
static int aev_law(aev_ctx* c, int law, const double* par, const double* u, const double* x, double* dz, double* y) {
  c->arg[0] = u; c->arg[1] = x; c->arg[2] = par; c->res[0] = dz; c->res[1] = y;
  switch (law) {
AEV_LAW_SWITCH
  }
  return 1;
}

/* the dense output's coefficients Q (N x 4) of N entries from the 7 stages k[0..6] */
static void aev_dense_coef(int64_t N, double* const* k, double (*Q)[4]) {
  for (int64_t j = 0; j < N; j++)
    for (int m = 0; m < 4; m++) {
      double acc = 0; for (int l = 0; l < 7; l++) acc += k[l][j] * DP_P[l][m];
      Q[j][m] = acc;
    }
}

/* the dense output of one vehicle's z (NZ entries) at theta in [0, 1] of a step of length h */
static void aev_dense(const double* z, const double (*Q)[4], double h, double th, double* out) {
  for (int k = 0; k < NZ; k++)
    out[k] = z[k] + h * th * (Q[k][0] + th * (Q[k][1] + th * (Q[k][2] + th * Q[k][3])));
}

/* first theta in (0, 1] where entry k of the dense output, as sign * value - off, becomes <= 0 (bisection) */
static double aev_root(const double* z, const double (*Q)[4], double h, int k, double sign, double off) {
  double lo = 0, hi = 1, buf[NZ];
  for (int it = 0; it < 60; it++) {
    double mid = 0.5 * (lo + hi);
    aev_dense(z, Q, h, mid, buf);
    if (sign * buf[k] - off > 0) lo = mid; else hi = mid;
  }
  return hi;
}
#endif
