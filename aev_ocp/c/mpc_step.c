/* mpc_step.c — driver of the exported MPC step of aev_ocp (hand-written; see mpc_step.h).
 * Runs the CasADi-generated functions of mpc_casadi.c (aev_ocp/mpc/export.py):
 *   aev_cg_guess(z0, p) -> x                          cold-start guess (closed-form law rolled out)
 *   aev_cg_shift(x, lam_g, lam_x, z0, p) -> x, lam_g, lam_x   warm start shifted by one interval
 *   aev_cg_sqp(x, lam_g, lam_x, p, reg) -> x+, lam_g+, lam_x+, |dx|inf, QP residual   one full SQP step
 *                                   (qrqp; Hessian + reg I, reg > 0 only in the cold start)
 *   aev_cg_node0(x, p) -> node-0 violation, u0
 *   aev_cg_eval(x, p) -> cost, violation                  (only in aev_mpc_get_info)
 * All memory is allocated in aev_mpc_create; a step allocates nothing.
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "mpc_config.h"
#include "mpc_casadi.h"
#include "mpc_step.h"

#define NB (AEV_MPC_NX + AEV_MPC_NU)

typedef int (*cg_work_t)(casadi_int *, casadi_int *, casadi_int *, casadi_int *);

struct aev_mpc_workspace {
  int warm;                           /* a warm start is available */
  int mem[5];                         /* CasADi memory ids of guess, shift, sqp, node0, eval */
  int evaluated;                      /* cost and violation of the plan are up to date */
  double *x, *lam_g, *lam_x;          /* current primal-dual point */
  double *x2, *lam_g2, *lam_x2;       /* buffers of the next point (swapped) */
  double *p, *z0;
  double *block;                      /* the one allocation of the arrays above */
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

aev_mpc_workspace *aev_mpc_create(void) {
  casadi_int sz[4] = {0, 0, 0, 0};
  aev_mpc_workspace *ws = (aev_mpc_workspace *)calloc(1, sizeof(aev_mpc_workspace));
  if (!ws) return NULL;
  grow(aev_cg_guess_work, sz); grow(aev_cg_shift_work, sz); grow(aev_cg_sqp_work, sz);
  grow(aev_cg_node0_work, sz); grow(aev_cg_eval_work, sz);
  ws->block = (double *)calloc(4 * AEV_MPC_NV + 2 * AEV_MPC_NG + AEV_MPC_NP + AEV_MPC_NX, sizeof(double));
  ws->x = ws->block;
  ws->arg = (const casadi_real **)calloc((size_t)sz[0] + 1, sizeof(casadi_real *));
  ws->res = (casadi_real **)calloc((size_t)sz[1] + 1, sizeof(casadi_real *));
  ws->iw = (casadi_int *)calloc((size_t)sz[2] + 1, sizeof(casadi_int));
  ws->w = (casadi_real *)calloc((size_t)sz[3] + 1, sizeof(casadi_real));
  if (!ws->block || !ws->arg || !ws->res || !ws->iw || !ws->w) {
    aev_mpc_free(ws);
    return NULL;
  }
  ws->lam_x = ws->x + AEV_MPC_NV;
  ws->x2 = ws->lam_x + AEV_MPC_NV;
  ws->lam_x2 = ws->x2 + AEV_MPC_NV;
  ws->lam_g = ws->lam_x2 + AEV_MPC_NV;
  ws->lam_g2 = ws->lam_g + AEV_MPC_NG;
  ws->p = ws->lam_g2 + AEV_MPC_NG;
  ws->z0 = ws->p + AEV_MPC_NP;
  aev_cg_guess_incref(); aev_cg_shift_incref(); aev_cg_sqp_incref(); aev_cg_node0_incref(); aev_cg_eval_incref();
  ws->mem[0] = aev_cg_guess_checkout();
  ws->mem[1] = aev_cg_shift_checkout();
  ws->mem[2] = aev_cg_sqp_checkout();
  ws->mem[3] = aev_cg_node0_checkout();
  ws->mem[4] = aev_cg_eval_checkout();
  ws->warm = 0;
  return ws;
}

void aev_mpc_free(aev_mpc_workspace *ws) {
  if (!ws) return;
  if (ws->arg && ws->block) {  /* fully created: give the CasADi memories back */
    aev_cg_guess_release(ws->mem[0]); aev_cg_shift_release(ws->mem[1]);
    aev_cg_sqp_release(ws->mem[2]); aev_cg_node0_release(ws->mem[3]); aev_cg_eval_release(ws->mem[4]);
    aev_cg_guess_decref(); aev_cg_shift_decref(); aev_cg_sqp_decref(); aev_cg_node0_decref(); aev_cg_eval_decref();
  }
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

/* One SQP step from (x, lam_g, lam_x) into the buffers, then swapped in. 0 ok, else a status. */
static int sqp_step(aev_mpc_workspace *ws, const double *reg) {
  int flag;
  ws->arg[0] = ws->x; ws->arg[1] = ws->lam_g; ws->arg[2] = ws->lam_x; ws->arg[3] = ws->p; ws->arg[4] = reg;
  ws->res[0] = ws->x2; ws->res[1] = ws->lam_g2; ws->res[2] = ws->lam_x2;
  ws->res[3] = &ws->info.step_inf; ws->res[4] = &ws->info.qp_residual;
  flag = aev_cg_sqp(ws->arg, ws->res, ws->iw, ws->w, ws->mem[2]);
  ws->info.iterations++;
  if (flag) return AEV_MPC_QP_FAILED;
  if (!isfinite(ws->info.step_inf) || !all_finite(ws->x2, AEV_MPC_NV)) return AEV_MPC_NONFINITE;
  swap(&ws->x, &ws->x2); swap(&ws->lam_g, &ws->lam_g2); swap(&ws->lam_x, &ws->lam_x2);
  return AEV_MPC_OK;
}

static int finish(aev_mpc_workspace *ws, int st, double *u_out, int *status) {
  int i;
  double u0[AEV_MPC_NU];
  if (st == AEV_MPC_OK) {
    ws->arg[0] = ws->x; ws->arg[1] = ws->p;
    ws->res[0] = &ws->info.node0_violation; ws->res[1] = u0;
    if (aev_cg_node0(ws->arg, ws->res, ws->iw, ws->w, ws->mem[3])) st = AEV_MPC_NONFINITE;
    else if (!isfinite(ws->info.node0_violation)) st = AEV_MPC_NONFINITE;
    else if (ws->info.node0_violation > AEV_MPC_PLAN_TOL) st = AEV_MPC_NODE0_VIOLATION;
  }
  ws->warm = (st == AEV_MPC_OK);
  ws->evaluated = 0;
  for (i = 0; i < AEV_MPC_NU; ++i) u_out[i] = (st == AEV_MPC_OK) ? u0[i] : NAN;
  *status = st;
  return st;
}

int aev_mpc_step_full(aev_mpc_workspace *ws, const double *z0, const double *p, double *u_out, int *status) {
  int it, st = AEV_MPC_OK;
  double reg = 0.0;
  ws->info.iterations = 0;
  ws->info.step_inf = ws->info.qp_residual = ws->info.cost = ws->info.violation = ws->info.node0_violation = NAN;
  if (!all_finite(z0, AEV_MPC_NX) || !all_finite(p, AEV_MPC_NP)) return finish(ws, AEV_MPC_BAD_INPUT, u_out, status);
  if (p != ws->p) memcpy(ws->p, p, sizeof(double) * AEV_MPC_NP);
  if (z0 != ws->z0) memcpy(ws->z0, z0, sizeof(double) * AEV_MPC_NX);
  ws->info.cold = !ws->warm;
  if (ws->warm) {
    reg = AEV_MPC_RTI_REG;
    ws->arg[0] = ws->x; ws->arg[1] = ws->lam_g; ws->arg[2] = ws->lam_x; ws->arg[3] = ws->z0; ws->arg[4] = ws->p;
    ws->res[0] = ws->x2; ws->res[1] = ws->lam_g2; ws->res[2] = ws->lam_x2;
    if (aev_cg_shift(ws->arg, ws->res, ws->iw, ws->w, ws->mem[1])) return finish(ws, AEV_MPC_NONFINITE, u_out, status);
    swap(&ws->x, &ws->x2); swap(&ws->lam_g, &ws->lam_g2); swap(&ws->lam_x, &ws->lam_x2);
    for (it = 0; it < AEV_MPC_RTI_ITER; ++it) {
      st = sqp_step(ws, &reg);
      if (st != AEV_MPC_OK || ws->info.step_inf <= AEV_MPC_TOL) break;
    }
  } else {
    ws->arg[0] = ws->z0; ws->arg[1] = ws->p; ws->res[0] = ws->x;
    if (aev_cg_guess(ws->arg, ws->res, ws->iw, ws->w, ws->mem[0])) return finish(ws, AEV_MPC_NONFINITE, u_out, status);
    memset(ws->lam_g, 0, sizeof(double) * AEV_MPC_NG);
    memset(ws->lam_x, 0, sizeof(double) * AEV_MPC_NV);
    st = AEV_MPC_COLD_NOT_CONVERGED;
    reg = AEV_MPC_COLD_REG0;
    for (it = 0; it < AEV_MPC_COLD_MAX_ITER; ++it) {
      int s = sqp_step(ws, &reg);
      if (s == AEV_MPC_QP_FAILED && reg > 0.0 && reg < AEV_MPC_COLD_REG_MAX) {  /* retry more regularised */
        reg *= 10.0;
        continue;
      }
      if (s != AEV_MPC_OK) { st = s; break; }
      if (reg == 0.0 && ws->info.step_inf <= AEV_MPC_TOL) { st = AEV_MPC_OK; break; }
      if (ws->info.step_inf < AEV_MPC_COLD_REG_STEP) reg = reg > 1e-6 ? 0.1 * reg : 0.0;
    }
  }
  return finish(ws, st, u_out, status);
}

int aev_mpc_step(aev_mpc_workspace *ws, const double *x_meas, const double *forecast, double *u_out, int *status) {
  int i, k, j;
  double *p = ws->p, *z0 = ws->z0;
  for (i = 0; i < AEV_MPC_NZ; ++i) z0[i] = x_meas[i];
  for (i = AEV_MPC_NZ; i < AEV_MPC_NX; ++i)  /* own states: the previous plan's node 1, else initial values */
    z0[i] = ws->warm ? ws->x[NB + i] * AEV_MPC_X_SCALE[i] : AEV_MPC_OWN0[i - AEV_MPC_NZ];
  for (k = 0; k < AEV_MPC_N; ++k) {
    p[k * AEV_MPC_NW] = forecast[k];
    p[k * AEV_MPC_NW + 1] = forecast[AEV_MPC_N + k];
    for (j = 0; j < AEV_MPC_NW_EXTRA; ++j) p[k * AEV_MPC_NW + 2 + j] = AEV_MPC_W_EXTRA[j];
  }
  for (j = 0; j < AEV_MPC_NPP; ++j) p[AEV_MPC_NW * AEV_MPC_N + j] = AEV_MPC_P_CONST[j];
  for (k = 0; k < AEV_MPC_N; ++k) p[AEV_MPC_NW * AEV_MPC_N + AEV_MPC_NPP + k] = 1.0;
  return aev_mpc_step_full(ws, z0, p, u_out, status);
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
