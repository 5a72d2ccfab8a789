/* mpc_step.h — the exported MPC step of aev_ocp (hand-written driver, aev_ocp/c/mpc_step.h).
 *
 * One real-time iteration of the receding-horizon controller per call: shift the previous plan by one
 * interval, linearise (exact Lagrangian Hessian), solve the QP with CasADi's generated qrqp (active set,
 * warm-started on the previous active set), return the first control. The first call (or the first after
 * aev_mpc_reset or a failure) is a cold start: SQP iterations from the closed-form law rolled out over the
 * horizon (Hessian regularised, AEV_MPC_COLD_REG0) until max|dx| <= AEV_MPC_TOL. No allocation after aev_mpc_create; not thread-safe per workspace.
 *
 * Units: the toolkit's model units (README.txt). Array layouts:
 *   x_meas   [AEV_MPC_NZ]      measured (h, v, V1, V2, S): gap, speed, RC voltages, state of charge
 *   forecast [2*AEV_MPC_N]     v_l_mean[0..N-1] (leader speed averaged over interval k), then
 *                              v_l_hat[0..N-1] (leader speed at the start of interval k)
 *   u_out    [AEV_MPC_NU]      controls of the first interval (u_out[0] = acceleration a); NaN on failure
 *   status                     AEV_MPC_OK or an error code below (then apply a fallback; the next call
 *                              is a cold start)
 */
#ifndef AEV_MPC_STEP_H
#define AEV_MPC_STEP_H

#ifdef __cplusplus
extern "C" {
#endif

enum {
  AEV_MPC_OK = 0,              /* step done, node-0 path constraints hold */
  AEV_MPC_QP_FAILED = 1,       /* the QP solver failed (infeasible or iteration limit) */
  AEV_MPC_NONFINITE = 2,       /* a non-finite step or plan */
  AEV_MPC_NODE0_VIOLATION = 3, /* the applied control violates the path constraints */
  AEV_MPC_COLD_NOT_CONVERGED = 4, /* the cold start did not converge within AEV_MPC_COLD_MAX_ITER */
  AEV_MPC_BAD_INPUT = 5        /* a non-finite measurement or forecast */
};

typedef struct aev_mpc_workspace aev_mpc_workspace;

typedef struct {
  int iterations;         /* SQP iterations (QPs) of the last step */
  int cold;               /* 1 if the last step was a cold start */
  double step_inf;        /* max |dx| of the last SQP iteration (scaled NLP variables) */
  double qp_residual;     /* max violation of the last QP's linear constraints */
  double cost;            /* NLP objective of the plan (NaN after a failed step) */
  double violation;       /* max nonlinear constraint violation of the plan (NLP units; NaN after a failure) */
  double node0_violation; /* max violation of the path constraints at node 0 */
} aev_mpc_info;

/* dims[8] = {N, NX, NU, NZ, NV, NG, NP, 2N (forecast length)} */
void aev_mpc_dims(int *dims);
/* One workspace (all memory of the step, allocated once); NULL if out of memory. */
aev_mpc_workspace *aev_mpc_create(void);
void aev_mpc_free(aev_mpc_workspace *ws);
/* Forget the warm start: the next step is a cold start. */
void aev_mpc_reset(aev_mpc_workspace *ws);
/* The MPC step from the measured state and the forecast (layouts above); returns *status. */
int aev_mpc_step(aev_mpc_workspace *ws, const double *x_meas, const double *forecast, double *u_out, int *status);
/* The same from the full initial state z0[NX] (own states included) and the NLP parameter vector p[NP]
 * (stage parameters per interval, problem parameters, stage weights). */
int aev_mpc_step_full(aev_mpc_workspace *ws, const double *z0, const double *p, double *u_out, int *status);
/* Warm start the next step from a primal-dual point: x[NV] (scaled), lam_g[NG], lam_x[NV]. */
void aev_mpc_set_warm(aev_mpc_workspace *ws, const double *x, const double *lam_g, const double *lam_x);
/* The last plan: x[NV] (scaled NLP vector), lam_g[NG], lam_x[NV] (any may be NULL). */
void aev_mpc_get_solution(const aev_mpc_workspace *ws, double *x, double *lam_g, double *lam_x);
/* Diagnostics of the last step; the plan's cost and violation are evaluated here (not in the step). */
void aev_mpc_get_info(aev_mpc_workspace *ws, aev_mpc_info *info);

#ifdef __cplusplus
}
#endif
#endif
