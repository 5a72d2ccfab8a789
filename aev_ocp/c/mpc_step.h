/* mpc_step.h — the exported MPC step of aev_ocp (hand-written driver, aev_ocp/c/mpc_step.h).
 *
 * One real-time iteration of the receding-horizon controller per call: shift the previous plan by one
 * interval, linearise (exact Lagrangian Hessian, its stage blocks projected onto the positive-definite cone
 * when AEV_MPC_PROJECT; else projected only for a QP that the exact one makes fail: the interior point needs
 * convexity), solve the QP with the Riccati interior point of ocp_qp.c, return the first control.
 * The first call (or the first after aev_mpc_reset or a failure) is a cold start from the closed-form law
 * rolled out over the horizon: AEV_MPC_COLD_ITER SQP steps, or (AEV_MPC_COLD_ITER = 0) regularised SQP
 * (Hessian + reg I from AEV_MPC_COLD_REG0) until max|dx| <= AEV_MPC_TOL. No allocation after aev_mpc_create;
 * not thread-safe per workspace.
 *
 * Units: SI at the API of aev_mpc_step and aev_mpc_step_own (call them every AEV_MPC_DT_S seconds); the
 * toolkit's model units only inside (and at aev_mpc_step_full, the NLP's own interface). Array layouts:
 *   x_meas   [AEV_MPC_NZ]      measured (h [m], v [m/s], V1 [V], V2 [V], S [-]): gap, speed, RC voltages,
 *                              state of charge
 *   forecast [2*AEV_MPC_N]     v_l_mean[0..N-1] [m/s] (leader speed averaged over interval k), then
 *                              v_l_hat[0..N-1] [m/s] (leader speed at the start of interval k)
 *   u_out    [AEV_MPC_NU]      controls of the first interval in SI (u_out[0] = acceleration a [m/s^2]; the
 *                              others: mpc_config.h, AEV_MPC_U_SI); NaN on failure
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
  AEV_MPC_QP_FAILED = 1,       /* the QP solver failed (iteration limit, a non-convex QP, inconsistent bounds) */
  AEV_MPC_NONFINITE = 2,       /* a non-finite step or plan */
  AEV_MPC_NODE0_VIOLATION = 3, /* the applied control violates the path constraints */
  AEV_MPC_COLD_NOT_CONVERGED = 4, /* the cold start did not converge within AEV_MPC_COLD_MAX_ITER */
  AEV_MPC_BAD_INPUT = 5        /* a non-finite measurement or forecast */
};

typedef struct aev_mpc_workspace aev_mpc_workspace;

typedef struct {
  int iterations;         /* SQP iterations (QPs) of the last step */
  int qp_iterations;      /* interior-point iterations of those QPs, summed */
  int qp_status;          /* ocpqp status of the last QP (ocp_qp.h: OCPQP_OK = 0) */
  int projected_retries;  /* QPs re-solved with the projected Hessian after the exact one failed */
  int cold;               /* 1 if the last step was a cold start */
  int qp_acceptable;      /* QPs of the last step taken at the acceptable level (OCPQP_ACCEPTABLE), not converged */
  double step_inf;        /* max |dx| of the last SQP iteration (scaled NLP variables) */
  double qp_residual;     /* max violation of the last QP's linear constraints */
  double cost;            /* NLP objective of the plan (NaN after a failed step) */
  double violation;       /* max nonlinear constraint violation of the plan (NLP units; NaN after a failure) */
  double node0_violation; /* max violation of the path constraints at node 0 */
  /* wall times [s] of the last step's parts (shift, QP data, Hessian projection, QP solves, node-0 check),
   * measured only in a build with -DAEV_MPC_PROFILE (POSIX clock_gettime), else 0 */
  double t_shift, t_qpdata, t_project, t_qp, t_node0;
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
/* The same with the controller's own states given in SI: own[NX - NZ] (e.g. a_prev [m/s^2] = the command really
 * applied last step, which after a fallback is not the plan's; own = NULL: as aev_mpc_step). */
int aev_mpc_step_own(aev_mpc_workspace *ws, const double *x_meas, const double *own, const double *forecast,
                     double *u_out, int *status);
/* The same in model units (the NLP's own interface: no conversion) from the full initial state z0[NX] (own
 * states included) and the NLP parameter vector p[NP] (stage parameters per interval, problem parameters, stage
 * weights); u_out in model units. */
int aev_mpc_step_full(aev_mpc_workspace *ws, const double *z0, const double *p, double *u_out, int *status);
/* Replace the problem's constants (any pointer may be NULL: kept): p_const[NPP] the problem parameters and
 * w_extra[NW_EXTRA] the constant stage parameters aev_mpc_step fills in, own0[NX - NZ] the own states' initial
 * values, k_const[NK] the constants after the NLP parameters (bounds, the guess law's coefficients). A workspace
 * starts with those of mpc_config.h. */
void aev_mpc_set_constants(aev_mpc_workspace *ws, const double *p_const, const double *w_extra, const double *own0,
                           const double *k_const);
/* Replace the SI factors (SI value = model value * factor): x_si[NX] per state, u_si[NU] per control (NULL:
 * kept). A workspace starts with mpc_config.h's AEV_MPC_X_SI, AEV_MPC_U_SI. */
void aev_mpc_set_si(aev_mpc_workspace *ws, const double *x_si, const double *u_si);
/* Warm start the next step from a primal-dual point: x[NV] (scaled), lam_g[NG], lam_x[NV]. */
void aev_mpc_set_warm(aev_mpc_workspace *ws, const double *x, const double *lam_g, const double *lam_x);
/* The last plan: x[NV] (scaled NLP vector), lam_g[NG], lam_x[NV] (any may be NULL). */
void aev_mpc_get_solution(const aev_mpc_workspace *ws, double *x, double *lam_g, double *lam_x);
/* Project the symmetric n x n column-major B (n <= AEV_MPC_PD_MAXN) onto the positive-definite cone in
 * place: symmetrised, eigenvalues below floor_rel (1 + max|lambda|) raised to it; a block that is PD with
 * that margin is left as it is. Returns 0 unchanged, 1 projected, -1 non-finite or n out of range. */
int aev_mpc_project_pd(double *B, int n, double floor_rel);
/* The last QP solved (or attempted), in the layouts of ocp_qp.h with nc = NG_STAGE - NX path constraints
 * per stage and no terminal ones; its initial state is 0 (the step of x_0). Hessian as passed to the solver
 * (projected, regularised). Any pointer may be NULL. */
void aev_mpc_last_qp(const aev_mpc_workspace *ws, double *H, double *g, double *E, double *e, double *C, double *lc,
                     double *uc, double *lbw, double *ubw);
/* Diagnostics of the last step; the plan's cost and violation are evaluated here (not in the step). */
void aev_mpc_get_info(aev_mpc_workspace *ws, aev_mpc_info *info);

#ifdef __cplusplus
}
#endif
#endif
