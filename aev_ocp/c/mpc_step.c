/* mpc_step.c — driver of the exported MPC step of aev_ocp (hand-written; see mpc_step.h).
 * Runs the CasADi-generated functions of mpc_casadi.c (aev_ocp/mpc/export.py) and the structure-exploiting
 * QP solver of ocp_qp.c (Riccati interior point):
 *   aev_cg_guess(z0, p) -> x                                 cold-start guess (closed-form law rolled out)
 *   aev_cg_shift(x, lam_g, lam_x, z0, p) -> x, lam_g, lam_x  warm start shifted by one interval
 *   aev_cg_qpdata(x, p, lam_g) -> H, g, E, e, C, lc, uc, lbw, ubw   the QP of one SQP step in stage blocks
 *                                   (exact Lagrangian Hessian blocks; ocp_qp.h gives the layouts)
 *   aev_cg_node0(x, p) -> node-0 violation, u0
 *   aev_cg_eval(x, p) -> cost, violation                     (only in aev_mpc_get_info)
 * One SQP step: the QP data, the Hessian blocks projected onto the positive-definite cone (AEV_MPC_PROJECT;
 * aev_mpc_project_pd) plus reg I (the cold start's Levenberg-Marquardt term), the QP (in a warm step
 * ocpqp_solve_warm from the shifted multipliers, AEV_MPC_QP_WARM; in the cold start ocpqp_solve), a full step.
 * All memory is allocated in aev_mpc_create; a step allocates nothing.
 */
#ifdef AEV_MPC_PROFILE  /* per-part wall times in aev_mpc_info (POSIX clock_gettime; off by default) */
#define _POSIX_C_SOURCE 199309L
#include <time.h>
static double now_s(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
#define TIC(v) double v = now_s()
#define TOC(v, field) (ws->info.field += now_s() - (v))
#else
#define TIC(v) (void)0
#define TOC(v, field) (void)0
#endif
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "mpc_config.h"
#include "mpc_casadi.h"
#include "ocp_qp.h"
#include "mpc_step.h"

#define NB (AEV_MPC_NX + AEV_MPC_NU)
#define NC (AEV_MPC_NG_STAGE - AEV_MPC_NX)
#define NH (AEV_MPC_N * NB * NB + AEV_MPC_NX * AEV_MPC_NX)
#define NE (AEV_MPC_N * AEV_MPC_NX * NB)
#define NCM (AEV_MPC_N * NC * NB)
/* 1: the QP of a warm (RTI) step starts from the previous solution's multipliers (ocpqp_solve_warm); 0: from
 * ocp_qp.c's cold start */
#ifndef AEV_MPC_QP_WARM
#define AEV_MPC_QP_WARM 1
#endif
#define NF 5                                /* generated functions: guess, shift, qpdata, node0, eval */

typedef int (*cg_work_t)(casadi_int *, casadi_int *, casadi_int *, casadi_int *);

struct aev_mpc_workspace {
  int warm;                           /* a warm start is available */
  int mem[NF];                        /* CasADi memory ids of guess, shift, qpdata, node0, eval */
  int evaluated;                      /* cost and violation of the plan are up to date */
  int created;                        /* the CasADi memories were checked out */
  double *x, *lam_g, *lam_x;          /* current primal-dual point */
  double *x2, *lam_g2, *lam_x2;       /* buffers of the next point (swapped) */
  double *p, *z0;                     /* p: NP NLP parameters, then the NK step constants */
  double *own0, *w_extra, *p_const;   /* aev_mpc_step's constants (from mpc_config.h, or aev_mpc_set_constants) */
  double *x_si, *u_si;                /* SI value = model value * factor, per state and per control */
  double *H, *g, *E, *e, *C, *lc, *uc, *lbw, *ubw, *x0, *dw, *pi, *lam_c;  /* QP data and solution */
  double *block;                      /* the one allocation of the arrays above */
  ocpqp_solver *qp;
  const casadi_real **arg;
  casadi_real **res;
  casadi_int *iw;
  casadi_real *w;
  aev_mpc_info info;
};

void aev_mpc_dims(int *dims) {
  dims[0] = AEV_MPC_N; dims[1] = AEV_MPC_NX; dims[2] = AEV_MPC_NU; dims[3] = AEV_MPC_NZ;
  dims[4] = AEV_MPC_NV; dims[5] = AEV_MPC_NG; dims[6] = AEV_MPC_NP; dims[7] = 2 * AEV_MPC_N;
}

static void grow(cg_work_t f, casadi_int *sz) {
  casadi_int a, r, i, w;
  f(&a, &r, &i, &w);
  if (a > sz[0]) sz[0] = a;
  if (r > sz[1]) sz[1] = r;
  if (i > sz[2]) sz[2] = i;
  if (w > sz[3]) sz[3] = w;
}

/* The workspace's arrays in its one block: points them into b (b NULL: only counts); returns the doubles
 * needed. The one place that lists them, so the allocation and the carving cannot disagree. */
static size_t layout(aev_mpc_workspace *ws, double *b) {
  struct { double **p; size_t n; } part[] = {
    {&ws->x, AEV_MPC_NV}, {&ws->lam_x, AEV_MPC_NV}, {&ws->x2, AEV_MPC_NV}, {&ws->lam_x2, AEV_MPC_NV},
    {&ws->lbw, AEV_MPC_NV}, {&ws->ubw, AEV_MPC_NV}, {&ws->g, AEV_MPC_NV}, {&ws->dw, AEV_MPC_NV},
    {&ws->lam_g, AEV_MPC_NG}, {&ws->lam_g2, AEV_MPC_NG}, {&ws->p, AEV_MPC_NP + AEV_MPC_NK}, {&ws->z0, AEV_MPC_NX},
    {&ws->own0, AEV_MPC_NX - AEV_MPC_NZ + 1}, {&ws->w_extra, AEV_MPC_NW_EXTRA + 1}, {&ws->p_const, AEV_MPC_NPP + 1},
    {&ws->x_si, AEV_MPC_NX}, {&ws->u_si, AEV_MPC_NU},
    {&ws->x0, AEV_MPC_NX},  /* the QP's initial state: 0 (x_0 = z0 is already in x) */
    {&ws->H, NH}, {&ws->E, NE}, {&ws->e, AEV_MPC_N * AEV_MPC_NX}, {&ws->C, NCM + 1},
    {&ws->lc, AEV_MPC_N * NC}, {&ws->uc, AEV_MPC_N * NC}, {&ws->pi, AEV_MPC_N * AEV_MPC_NX},
    {&ws->lam_c, AEV_MPC_N * NC + 1}};
  size_t i, total = 0;
  for (i = 0; i < sizeof(part) / sizeof(part[0]); ++i) {
    if (b) *part[i].p = b + total;
    total += part[i].n;
  }
  return total;
}

aev_mpc_workspace *aev_mpc_create(void) {
  casadi_int sz[4] = {0, 0, 0, 0};
  ocpqp_dims dims;
  ocpqp_settings qs;
  aev_mpc_workspace *ws = (aev_mpc_workspace *)calloc(1, sizeof(aev_mpc_workspace));
  if (!ws) return NULL;
  grow(aev_cg_guess_work, sz); grow(aev_cg_shift_work, sz); grow(aev_cg_qpdata_work, sz);
  grow(aev_cg_node0_work, sz); grow(aev_cg_eval_work, sz);
  ws->block = (double *)calloc(layout(ws, NULL), sizeof(double));
  ws->arg = (const casadi_real **)calloc((size_t)sz[0] + 1, sizeof(casadi_real *));
  ws->res = (casadi_real **)calloc((size_t)sz[1] + 1, sizeof(casadi_real *));
  ws->iw = (casadi_int *)calloc((size_t)sz[2] + 1, sizeof(casadi_int));
  ws->w = (casadi_real *)calloc((size_t)sz[3] + 1, sizeof(casadi_real));
  dims.N = AEV_MPC_N; dims.nx = AEV_MPC_NX; dims.nu = AEV_MPC_NU; dims.nc = NC; dims.ncN = 0;
  ocpqp_default_settings(&qs);
  qs.max_iter = AEV_MPC_QP_MAX_ITER;
  qs.tol_stat = qs.tol_eq = qs.tol_ineq = qs.tol_comp = AEV_MPC_QP_TOL;
  ws->qp = ocpqp_create(&dims, &qs);
  if (!ws->block || !ws->arg || !ws->res || !ws->iw || !ws->w || !ws->qp) {
    aev_mpc_free(ws);
    return NULL;
  }
  layout(ws, ws->block);
  aev_mpc_set_constants(ws, AEV_MPC_P_CONST, AEV_MPC_W_EXTRA, AEV_MPC_OWN0, AEV_MPC_K_CONST);
  aev_mpc_set_si(ws, AEV_MPC_X_SI, AEV_MPC_U_SI);
  aev_cg_guess_incref(); aev_cg_shift_incref(); aev_cg_qpdata_incref(); aev_cg_node0_incref(); aev_cg_eval_incref();
  ws->mem[0] = aev_cg_guess_checkout();
  ws->mem[1] = aev_cg_shift_checkout();
  ws->mem[2] = aev_cg_qpdata_checkout();
  ws->mem[3] = aev_cg_node0_checkout();
  ws->mem[4] = aev_cg_eval_checkout();
  ws->created = 1;
  ws->warm = 0;
  return ws;
}

void aev_mpc_free(aev_mpc_workspace *ws) {
  if (!ws) return;
  if (ws->created) {  /* give the CasADi memories back */
    aev_cg_guess_release(ws->mem[0]); aev_cg_shift_release(ws->mem[1]);
    aev_cg_qpdata_release(ws->mem[2]); aev_cg_node0_release(ws->mem[3]); aev_cg_eval_release(ws->mem[4]);
    aev_cg_guess_decref(); aev_cg_shift_decref(); aev_cg_qpdata_decref(); aev_cg_node0_decref(); aev_cg_eval_decref();
  }
  ocpqp_free(ws->qp);
  free(ws->block); free((void *)ws->arg); free(ws->res); free(ws->iw); free(ws->w);
  free(ws);
}

void aev_mpc_reset(aev_mpc_workspace *ws) { ws->warm = 0; }

static void swap(double **a, double **b) { double *t = *a; *a = *b; *b = t; }

static int all_finite(const double *v, int n) {
  int i;
  for (i = 0; i < n; ++i) if (!isfinite(v[i])) return 0;
  return 1;
}

/* ---------------------------------------------------------------- projection onto the PD cone */
/* Cholesky of the n x n column-major A - shift I into L (lower); 1 if every pivot is > 0. */
static int chol_ok(const double *A, int n, double shift, double *L) {
  int i, j, k;
  for (j = 0; j < n; ++j) {
    double d = A[j + j * n] - shift;
    for (k = 0; k < j; ++k) d -= L[j + k * n] * L[j + k * n];
    if (!(d > 0.0)) return 0;
    d = sqrt(d);
    L[j + j * n] = d;
    for (i = j + 1; i < n; ++i) {
      double s = A[i + j * n];
      for (k = 0; k < j; ++k) s -= L[i + k * n] * L[j + k * n];
      L[i + j * n] = s / d;
    }
  }
  return 1;
}

/* sqrt(a^2 + b^2) without overflow or underflow in the squares (libm's hypot only where they would) */
static double hyp(double a, double b) {
  double t = a * a + b * b;
  return (t > 1e-290 && t < 1e290) ? sqrt(t) : hypot(a, b);
}

/* Eigen-decomposition of the symmetric n x n A (column-major; read, not changed): Householder reduction to
 * tridiagonal form, then the implicit QL iteration with Wilkinson-type shifts, the eigenvectors accumulated
 * (EISPACK's tred2 and tql2: Smith et al., Matrix Eigensystem Routines, 2nd ed., Springer 1976; in the order of
 * the public-domain JAMA EigenvalueDecomposition). Eigenvalues in lam (unsorted), eigenvectors in the columns of
 * Q (n x n, column-major). On the 28 000 stage blocks of a recorded canonical loop (6 x 6, all indefinite)
 * aev_mpc_project_pd takes 0.77x its time with the round-robin Jacobi rotations this replaces (issue 40); the
 * rebuilt blocks are within 4e-15 (relative to the block's largest entry) of numpy.linalg.eigh's. */
static void sym_eig(const double *A, int n, double *lam, double *Q) {
  double e[AEV_MPC_PD_MAXN], *d = lam, f, g, h, hh, scale, p, r, c, c2, c3, s, s2, el1, dl1, tst1;
  const double eps = 2.220446049250313e-16;  /* 2^-52 */
  int i, j, k, l, m, iter;
#define V(r_, c_) Q[(r_) + (c_) * n]
  for (j = 0; j < n * n; ++j) Q[j] = A[j];
  for (j = 0; j < n; ++j) d[j] = V(n - 1, j);
  for (i = n - 1; i > 0; --i) {  /* tred2: Householder reduction */
    scale = 0.0; h = 0.0;
    for (k = 0; k < i; ++k) scale += fabs(d[k]);
    if (scale == 0.0) {
      e[i] = d[i - 1];
      for (j = 0; j < i; ++j) { d[j] = V(i - 1, j); V(i, j) = 0.0; V(j, i) = 0.0; }
    } else {
      for (k = 0; k < i; ++k) { d[k] /= scale; h += d[k] * d[k]; }
      f = d[i - 1];
      g = sqrt(h);
      if (f > 0) g = -g;
      e[i] = scale * g;
      h -= f * g;
      d[i - 1] = f - g;
      for (j = 0; j < i; ++j) e[j] = 0.0;
      for (j = 0; j < i; ++j) {
        f = d[j];
        V(j, i) = f;
        g = e[j] + V(j, j) * f;
        for (k = j + 1; k <= i - 1; ++k) { g += V(k, j) * d[k]; e[k] += V(k, j) * f; }
        e[j] = g;
      }
      f = 0.0;
      for (j = 0; j < i; ++j) { e[j] /= h; f += e[j] * d[j]; }
      hh = f / (h + h);
      for (j = 0; j < i; ++j) e[j] -= hh * d[j];
      for (j = 0; j < i; ++j) {
        f = d[j]; g = e[j];
        for (k = j; k <= i - 1; ++k) V(k, j) -= (f * e[k] + g * d[k]);
        d[j] = V(i - 1, j);
        V(i, j) = 0.0;
      }
    }
    d[i] = h;
  }
  for (i = 0; i < n - 1; ++i) {  /* the transformations accumulated */
    V(n - 1, i) = V(i, i);
    V(i, i) = 1.0;
    h = d[i + 1];
    if (h != 0.0) {
      for (k = 0; k <= i; ++k) d[k] = V(k, i + 1) / h;
      for (j = 0; j <= i; ++j) {
        g = 0.0;
        for (k = 0; k <= i; ++k) g += V(k, i + 1) * V(k, j);
        for (k = 0; k <= i; ++k) V(k, j) -= g * d[k];
      }
    }
    for (k = 0; k <= i; ++k) V(k, i + 1) = 0.0;
  }
  for (j = 0; j < n; ++j) { d[j] = V(n - 1, j); V(n - 1, j) = 0.0; }
  V(n - 1, n - 1) = 1.0;
  e[0] = 0.0;
  for (i = 1; i < n; ++i) e[i - 1] = e[i];  /* tql2: implicit QL */
  e[n - 1] = 0.0;
  f = 0.0; tst1 = 0.0;
  for (l = 0; l < n; ++l) {
    if (fabs(d[l]) + fabs(e[l]) > tst1) tst1 = fabs(d[l]) + fabs(e[l]);
    for (m = l; m < n - 1; ++m) if (fabs(e[m]) <= eps * tst1) break;
    if (m > l) {
      iter = 0;
      do {
        g = d[l];
        p = (d[l + 1] - g) / (2.0 * e[l]);
        r = hyp(p, 1.0);
        if (p < 0) r = -r;
        d[l] = e[l] / (p + r);
        d[l + 1] = e[l] * (p + r);
        dl1 = d[l + 1];
        h = g - d[l];
        for (i = l + 2; i < n; ++i) d[i] -= h;
        f += h;
        p = d[m];
        c = c2 = c3 = 1.0;
        el1 = e[l + 1];
        s = s2 = 0.0;
        for (i = m - 1; i >= l; --i) {
          c3 = c2; c2 = c; s2 = s;
          g = c * e[i];
          h = c * p;
          r = hyp(p, e[i]);
          e[i + 1] = s * r;
          s = e[i] / r;
          c = p / r;
          p = c * d[i] - s * g;
          d[i + 1] = h + s * (c * g + s * d[i]);
          for (k = 0; k < n; ++k) {
            h = V(k, i + 1);
            V(k, i + 1) = s * V(k, i) + c * h;
            V(k, i) = c * V(k, i) - s * h;
          }
        }
        p = -s * s2 * c3 * el1 * e[l] / dl1;
        e[l] = s * p;
        d[l] = c * p;
      } while (fabs(e[l]) > eps * tst1 && ++iter < 30 * n);
    }
    d[l] += f;
    e[l] = 0.0;
  }
#undef V
}

int aev_mpc_project_pd(double *B, int n, double floor_rel) {
  double S[AEV_MPC_PD_MAXN * AEV_MPC_PD_MAXN], Q[AEV_MPC_PD_MAXN * AEV_MPC_PD_MAXN], lam[AEV_MPC_PD_MAXN];
  double lk[AEV_MPC_PD_MAXN], norm = 0.0, big = 0.0, fl;
  int i, j, k, low = 0, m = 0, cp[AEV_MPC_PD_MAXN], coupled[AEV_MPC_PD_MAXN];
  if (n <= 0 || n > AEV_MPC_PD_MAXN || !all_finite(B, n * n)) return -1;
  for (j = 0; j < n; ++j)
    for (i = 0; i < j; ++i) B[i + j * n] = B[j + i * n] = 0.5 * (B[i + j * n] + B[j + i * n]);
  for (i = 0; i < n; ++i) {  /* max |lambda| <= the infinity norm: a PD test with the larger floor suffices */
    double r = 0.0;
    for (j = 0; j < n; ++j) r += fabs(B[i + j * n]);
    if (r > norm) norm = r;
  }
  if (chol_ok(B, n, floor_rel * (1.0 + norm), S)) return 0;
  /* a variable without off-diagonal entries (e.g. a control that enters the cost only as its square) is its own
   * eigenvector: only the coupled ones (cp, m of them) go through the eigen-decomposition */
  for (i = 0; i < n; ++i) {
    coupled[i] = 0;
    for (j = 0; j < n; ++j)
      if (j != i && B[i + j * n] != 0.0) coupled[i] = 1;
    if (coupled[i]) cp[m++] = i;
  }
  for (j = 0; j < m; ++j)
    for (i = 0; i < m; ++i) S[i + j * m] = B[cp[i] + cp[j] * n];
  sym_eig(S, m, lk, Q);
  for (i = 0, k = 0; i < n; ++i) lam[i] = coupled[i] ? lk[k++] : B[i + i * n];
  for (i = 0; i < n; ++i) if (fabs(lam[i]) > big) big = fabs(lam[i]);
  fl = floor_rel * (1.0 + big);
  for (i = 0; i < n; ++i) if (lam[i] < fl) { lam[i] = fl; low = 1; }
  if (!low) return 0;  /* PD with margin after all: unchanged, as aev_ocp.mpc.controller._project_pd */
  for (i = 0; i < m; ++i) lk[i] = lam[cp[i]];
  for (j = 0; j < n; ++j)
    for (i = 0; i < n; ++i) B[i + j * n] = (i == j && !coupled[i]) ? lam[i] : 0.0;
  for (j = 0; j < m; ++j)
    for (i = 0; i < m; ++i) {
      double s = 0.0;
      for (k = 0; k < m; ++k) s += Q[i + k * m] * lk[k] * Q[j + k * m];
      B[cp[i] + cp[j] * n] = s;
    }
  return 1;
}

/* ---------------------------------------------------------------- one SQP step */
/* The QP's Hessian blocks (stages and terminal) projected onto the PD cone in place; 1 if non-finite. */
static int project_hessian(aev_mpc_workspace *ws) {
  int k;
  TIC(t1);
  for (k = 0; k < AEV_MPC_N; ++k)
    if (aev_mpc_project_pd(ws->H + k * NB * NB, NB, AEV_MPC_HESS_FLOOR) < 0) return 1;
  if (aev_mpc_project_pd(ws->H + AEV_MPC_N * NB * NB, AEV_MPC_NX, AEV_MPC_HESS_FLOOR) < 0) return 1;
  TOC(t1, t_project);
  return 0;
}

/* One SQP step from (x, lam_g, lam_x) into the buffers, then swapped in. 0 ok, else a status. warm: the QP
 * starts from the step dw = 0 and the multipliers (lam_g, lam_x) (ocpqp_solve_warm, which falls back to the cold
 * start itself); else from ocp_qp.c's cold start. */
static int sqp_step(aev_mpc_workspace *ws, double reg, int warm) {
  int k, i, flag;
  ocpqp_data d;
  ocpqp_info qi;
  double step = 0.0;
  TIC(t0);
  ws->arg[0] = ws->x; ws->arg[1] = ws->p; ws->arg[2] = ws->lam_g;
  ws->res[0] = ws->H; ws->res[1] = ws->g; ws->res[2] = ws->E; ws->res[3] = ws->e; ws->res[4] = ws->C;
  ws->res[5] = ws->lc; ws->res[6] = ws->uc; ws->res[7] = ws->lbw; ws->res[8] = ws->ubw;
  flag = aev_cg_qpdata(ws->arg, ws->res, ws->iw, ws->w, ws->mem[2]);
  TOC(t0, t_qpdata);
  ws->info.iterations++;
  if (flag) return AEV_MPC_NONFINITE;
  if (AEV_MPC_PROJECT && project_hessian(ws)) return AEV_MPC_NONFINITE;
  if (reg > 0.0) {
    for (k = 0; k < AEV_MPC_N; ++k)
      for (i = 0; i < NB; ++i) ws->H[k * NB * NB + i * (NB + 1)] += reg;
    for (i = 0; i < AEV_MPC_NX; ++i) ws->H[AEV_MPC_N * NB * NB + i * (AEV_MPC_NX + 1)] += reg;
  }
  d.H = ws->H; d.g = ws->g; d.E = ws->E; d.e = ws->e; d.C = ws->C; d.lc = ws->lc; d.uc = ws->uc;
  d.lbw = ws->lbw; d.ubw = ws->ubw; d.x0 = ws->x0;
  {
    TIC(t2);
    if (warm) {
      for (k = 0; k < AEV_MPC_N; ++k) {  /* the multiplier guess in the QP's layout (pi, lam_c: its outputs) */
        memcpy(ws->pi + k * AEV_MPC_NX, ws->lam_g + k * AEV_MPC_NG_STAGE, sizeof(double) * AEV_MPC_NX);
        if (NC > 0) memcpy(ws->lam_c + k * NC, ws->lam_g + k * AEV_MPC_NG_STAGE + AEV_MPC_NX, sizeof(double) * NC);
      }
      flag = ocpqp_solve_warm(ws->qp, &d, NULL, ws->pi, ws->lam_x, ws->lam_c, ws->dw, ws->pi, ws->lam_x2, ws->lam_c,
                              &qi);
    } else {
      flag = ocpqp_solve(ws->qp, &d, ws->dw, ws->pi, ws->lam_x2, ws->lam_c, &qi);
    }
    TOC(t2, t_qp);
  }
  if (!AEV_MPC_PROJECT && (flag == OCPQP_MAX_ITER || flag == OCPQP_FACTORIZATION || flag == OCPQP_ACCEPTABLE)) {
    /* the exact Hessian was not convex enough for the interior point: the same QP once more with its
     * blocks projected onto the PD cone (as rti_hessian 'projected' always does) */
    ws->info.qp_iterations += qi.iterations;
    ws->info.projected_retries++;
    if (project_hessian(ws)) return AEV_MPC_NONFINITE;
    {
      TIC(t3);
      flag = ocpqp_solve(ws->qp, &d, ws->dw, ws->pi, ws->lam_x2, ws->lam_c, &qi);
      TOC(t3, t_qp);
    }
  }
  ws->info.qp_iterations += qi.iterations;
  ws->info.qp_status = flag;
  ws->info.qp_residual = qi.res_eq > qi.res_ineq ? qi.res_eq : qi.res_ineq;
  /* an acceptable QP (every residual within 100x the tolerance, ocp_qp.h) is taken, and counted: as acados'
   * RTI takes a QP at its iteration limit, but only with small residuals */
  if (flag == OCPQP_ACCEPTABLE) ws->info.qp_acceptable++;
  else if (flag != OCPQP_OK) return flag == OCPQP_NONFINITE ? AEV_MPC_NONFINITE : AEV_MPC_QP_FAILED;
  for (i = 0; i < AEV_MPC_NV; ++i) {
    double di = ws->dw[i];
    if (fabs(di) > step) step = fabs(di);
    ws->x2[i] = ws->x[i] + di;
  }
  ws->info.step_inf = step;
  if (!isfinite(step) || !all_finite(ws->x2, AEV_MPC_NV)) return AEV_MPC_NONFINITE;
  for (k = 0; k < AEV_MPC_N; ++k) {  /* the NLP's constraints per interval: the gap (NX), then the path (NC) */
    memcpy(ws->lam_g2 + k * AEV_MPC_NG_STAGE, ws->pi + k * AEV_MPC_NX, sizeof(double) * AEV_MPC_NX);
    if (NC > 0) memcpy(ws->lam_g2 + k * AEV_MPC_NG_STAGE + AEV_MPC_NX, ws->lam_c + k * NC, sizeof(double) * NC);
  }
  swap(&ws->x, &ws->x2); swap(&ws->lam_g, &ws->lam_g2); swap(&ws->lam_x, &ws->lam_x2);
  return AEV_MPC_OK;
}

static int finish(aev_mpc_workspace *ws, int st, double *u_out, int *status) {
  int i;
  double u0[AEV_MPC_NU];
  if (st == AEV_MPC_OK) {
    TIC(t0);
    ws->arg[0] = ws->x; ws->arg[1] = ws->p;
    ws->res[0] = &ws->info.node0_violation; ws->res[1] = u0;
    if (aev_cg_node0(ws->arg, ws->res, ws->iw, ws->w, ws->mem[3])) st = AEV_MPC_NONFINITE;
    else if (!isfinite(ws->info.node0_violation)) st = AEV_MPC_NONFINITE;
    else if (ws->info.node0_violation > AEV_MPC_PLAN_TOL) st = AEV_MPC_NODE0_VIOLATION;
    TOC(t0, t_node0);
  }
  ws->warm = (st == AEV_MPC_OK);
  ws->evaluated = 0;
  for (i = 0; i < AEV_MPC_NU; ++i) u_out[i] = (st == AEV_MPC_OK) ? u0[i] : NAN;
  *status = st;
  return st;
}

/* The cold start. AEV_MPC_COLD_ITER > 0: that many plain SQP steps (the Python rti path's
 * rti_cold_iterations, with the projected Hessian); 0: regularised SQP (Levenberg-Marquardt) until
 * max|dx| <= AEV_MPC_TOL, at most AEV_MPC_COLD_MAX_ITER QPs (the exact, possibly indefinite Hessian). */
static int cold_start(aev_mpc_workspace *ws) {
  int it, st;
  double reg = AEV_MPC_COLD_REG0;
  if (AEV_MPC_COLD_ITER > 0) {
    for (it = 0; it < AEV_MPC_COLD_ITER; ++it) {
      st = sqp_step(ws, 0.0, 0);
      if (st != AEV_MPC_OK || ws->info.step_inf <= AEV_MPC_TOL) return st;
    }
    return AEV_MPC_OK;
  }
  for (it = 0; it < AEV_MPC_COLD_MAX_ITER; ++it) {
    st = sqp_step(ws, reg, 0);
    if (st == AEV_MPC_QP_FAILED && reg > 0.0 && reg < AEV_MPC_COLD_REG_MAX) {  /* retry more regularised */
      reg *= 10.0;
      continue;
    }
    if (st != AEV_MPC_OK) return st;
    if (reg == 0.0 && ws->info.step_inf <= AEV_MPC_TOL) return AEV_MPC_OK;
    if (ws->info.step_inf < AEV_MPC_COLD_REG_STEP) reg = reg > 1e-6 ? 0.1 * reg : 0.0;
  }
  return AEV_MPC_COLD_NOT_CONVERGED;
}

int aev_mpc_step_full(aev_mpc_workspace *ws, const double *z0, const double *p, double *u_out, int *status) {
  int it, st = AEV_MPC_OK;
  ws->info.iterations = ws->info.qp_iterations = ws->info.qp_status = ws->info.projected_retries = 0;
  ws->info.qp_acceptable = 0;
  ws->info.t_shift = ws->info.t_qpdata = ws->info.t_project = ws->info.t_qp = ws->info.t_node0 = 0.0;
  ws->info.step_inf = ws->info.qp_residual = ws->info.cost = ws->info.violation = ws->info.node0_violation = NAN;
  ws->info.cold = !ws->warm;
  if (!all_finite(z0, AEV_MPC_NX) || !all_finite(p, AEV_MPC_NP)) return finish(ws, AEV_MPC_BAD_INPUT, u_out, status);
  if (p != ws->p) memcpy(ws->p, p, sizeof(double) * AEV_MPC_NP);
  if (z0 != ws->z0) memcpy(ws->z0, z0, sizeof(double) * AEV_MPC_NX);
  if (ws->warm) {
    TIC(t0);
    ws->arg[0] = ws->x; ws->arg[1] = ws->lam_g; ws->arg[2] = ws->lam_x; ws->arg[3] = ws->z0; ws->arg[4] = ws->p;
    ws->res[0] = ws->x2; ws->res[1] = ws->lam_g2; ws->res[2] = ws->lam_x2;
    if (aev_cg_shift(ws->arg, ws->res, ws->iw, ws->w, ws->mem[1])) return finish(ws, AEV_MPC_NONFINITE, u_out, status);
    TOC(t0, t_shift);
    swap(&ws->x, &ws->x2); swap(&ws->lam_g, &ws->lam_g2); swap(&ws->lam_x, &ws->lam_x2);
    for (it = 0; it < AEV_MPC_RTI_ITER; ++it) {
      st = sqp_step(ws, AEV_MPC_RTI_REG, AEV_MPC_QP_WARM);
      if (st != AEV_MPC_OK || ws->info.step_inf <= AEV_MPC_TOL) break;
    }
  } else {
    ws->arg[0] = ws->z0; ws->arg[1] = ws->p; ws->res[0] = ws->x;
    if (aev_cg_guess(ws->arg, ws->res, ws->iw, ws->w, ws->mem[0])) return finish(ws, AEV_MPC_NONFINITE, u_out, status);
    memset(ws->lam_g, 0, sizeof(double) * AEV_MPC_NG);
    memset(ws->lam_x, 0, sizeof(double) * AEV_MPC_NV);
    st = cold_start(ws);
  }
  return finish(ws, st, u_out, status);
}

int aev_mpc_step(aev_mpc_workspace *ws, const double *x_meas, const double *forecast, double *u_out, int *status) {
  return aev_mpc_step_own(ws, x_meas, NULL, forecast, u_out, status);
}

int aev_mpc_step_own(aev_mpc_workspace *ws, const double *x_meas, const double *own, const double *forecast,
                     double *u_out, int *status) {
  int i, k, j, st;
  double *p = ws->p, *z0 = ws->z0, vs = ws->x_si[1];  /* SI in and out; model units inside */
  for (i = 0; i < AEV_MPC_NZ; ++i) z0[i] = x_meas[i] / ws->x_si[i];
  for (i = AEV_MPC_NZ; i < AEV_MPC_NX; ++i)  /* own states: given, else the previous plan's node 1, else initial */
    z0[i] = own ? own[i - AEV_MPC_NZ] / ws->x_si[i]
                : ws->warm ? ws->x[NB + i] * AEV_MPC_X_SCALE[i] : ws->own0[i - AEV_MPC_NZ];
  for (k = 0; k < AEV_MPC_N; ++k) {
    p[k * AEV_MPC_NW] = forecast[k] / vs;
    p[k * AEV_MPC_NW + 1] = forecast[AEV_MPC_N + k] / vs;
    for (j = 0; j < AEV_MPC_NW_EXTRA; ++j) p[k * AEV_MPC_NW + 2 + j] = ws->w_extra[j];
  }
  for (j = 0; j < AEV_MPC_NPP; ++j) p[AEV_MPC_NW * AEV_MPC_N + j] = ws->p_const[j];
  for (k = 0; k < AEV_MPC_N; ++k) p[AEV_MPC_NW * AEV_MPC_N + AEV_MPC_NPP + k] = 1.0;
  st = aev_mpc_step_full(ws, z0, p, u_out, status);
  for (i = 0; i < AEV_MPC_NU; ++i) u_out[i] *= ws->u_si[i];
  return st;
}

void aev_mpc_set_si(aev_mpc_workspace *ws, const double *x_si, const double *u_si) {
  if (x_si) memcpy(ws->x_si, x_si, sizeof(double) * AEV_MPC_NX);
  if (u_si) memcpy(ws->u_si, u_si, sizeof(double) * AEV_MPC_NU);
}

void aev_mpc_set_constants(aev_mpc_workspace *ws, const double *p_const, const double *w_extra, const double *own0,
                           const double *k_const) {
  if (p_const) memcpy(ws->p_const, p_const, sizeof(double) * AEV_MPC_NPP);
  if (w_extra) memcpy(ws->w_extra, w_extra, sizeof(double) * AEV_MPC_NW_EXTRA);
  if (own0) memcpy(ws->own0, own0, sizeof(double) * (AEV_MPC_NX - AEV_MPC_NZ));
  if (k_const) memcpy(ws->p + AEV_MPC_NP, k_const, sizeof(double) * AEV_MPC_NK);
}

void aev_mpc_set_warm(aev_mpc_workspace *ws, const double *x, const double *lam_g, const double *lam_x) {
  memcpy(ws->x, x, sizeof(double) * AEV_MPC_NV);
  memcpy(ws->lam_g, lam_g, sizeof(double) * AEV_MPC_NG);
  memcpy(ws->lam_x, lam_x, sizeof(double) * AEV_MPC_NV);
  ws->warm = 1;
}

void aev_mpc_get_solution(const aev_mpc_workspace *ws, double *x, double *lam_g, double *lam_x) {
  if (x) memcpy(x, ws->x, sizeof(double) * AEV_MPC_NV);
  if (lam_g) memcpy(lam_g, ws->lam_g, sizeof(double) * AEV_MPC_NG);
  if (lam_x) memcpy(lam_x, ws->lam_x, sizeof(double) * AEV_MPC_NV);
}

void aev_mpc_get_info(aev_mpc_workspace *ws, aev_mpc_info *info) {
  if (ws->warm && !ws->evaluated) {  /* the plan's cost and violation, evaluated on demand */
    ws->arg[0] = ws->x; ws->arg[1] = ws->p;
    ws->res[0] = &ws->info.cost; ws->res[1] = &ws->info.violation;
    if (aev_cg_eval(ws->arg, ws->res, ws->iw, ws->w, ws->mem[4])) ws->info.cost = ws->info.violation = NAN;
    ws->evaluated = 1;
  }
  *info = ws->info;
}

void aev_mpc_last_qp(const aev_mpc_workspace *ws, double *H, double *g, double *E, double *e, double *C, double *lc,
                     double *uc, double *lbw, double *ubw) {
  if (H) memcpy(H, ws->H, sizeof(double) * NH);
  if (g) memcpy(g, ws->g, sizeof(double) * AEV_MPC_NV);
  if (E) memcpy(E, ws->E, sizeof(double) * NE);
  if (e) memcpy(e, ws->e, sizeof(double) * AEV_MPC_N * AEV_MPC_NX);
  if (C) memcpy(C, ws->C, sizeof(double) * NCM);
  if (lc) memcpy(lc, ws->lc, sizeof(double) * AEV_MPC_N * NC);
  if (uc) memcpy(uc, ws->uc, sizeof(double) * AEV_MPC_N * NC);
  if (lbw) memcpy(lbw, ws->lbw, sizeof(double) * AEV_MPC_NV);
  if (ubw) memcpy(ubw, ws->ubw, sizeof(double) * AEV_MPC_NV);
}
