/* ocp_qp.h — the OCP QP interface of aev_ocp: one header, two backends with the same data, outputs and status
 * codes (aev_ocp.mpc.ocpqp.OcpQP(backend=...)):
 *   ocp_qp.c       (ours, the default; the only one in the exported MPC step): hand-written C99, no
 *                  allocation after ocpqp_create, no dependency but libm. Primal-dual interior point (Mehrotra
 *                  predictor-corrector); each Newton system is solved by a Riccati recursion over the stages,
 *                  so a solve costs O(N (nx+nu)^3) per iteration.
 *   ocp_qp_hpipm.c HPIPM's C API (d_ocp_qp_ipm_solve, mode SPEED, BALANCE or ROBUST) linked with the
 *                  libhpipm.so of the casadi wheel; ocpqp_create = mode BALANCE, ocpqp_hpipm_create(.., mode).
 * Neither detects primal infeasibility: inconsistent bounds (lb > ub) are OCPQP_INFEASIBLE before the solve;
 * a QP whose consistent constraints have no common point ends at the iteration limit (OCPQP_MAX_ITER).
 *
 * The QP (stage k = 0..N-1, w_k = (x_k, u_k) in R^nb, nb = nx + nu; the terminal w_N = x_N):
 *   min  sum_{k<N} 1/2 w_k' H_k w_k + g_k' w_k  +  1/2 x_N' H_N x_N + g_N' x_N
 *   s.t. x_{k+1} = E_k w_k + e_k               k = 0..N-1     (E_k = [A_k B_k], nx x nb)
 *        x_0 = x0                                               (fixed; the x part of lbw_0/ubw_0 is ignored)
 *        lbw_k <= w_k <= ubw_k                 k = 0..N       (a bound with |value| >= OCPQP_INF is absent)
 *        lc_k <= C_k w_k <= uc_k               k = 0..N-1     (nc rows, C_k nc x nb)
 *        lc_N <= C_N x_N <= uc_N                              (ncN rows, C_N ncN x nx)
 * Layouts (all matrices column-major, the stages' blocks one after the other):
 *   H   N blocks nb x nb, then nx x nx   (symmetric, both triangles stored)
 *   g   N*nb + nx        E  N blocks nx x nb      e  N*nx
 *   C   N blocks nc x nb, then ncN x nx           lc, uc  N*nc + ncN
 *   lbw, ubw, w, lam_w   N*nb + nx   (= the stacked (x_0, u_0, x_1, u_1, ..., x_N))
 *   pi  N*nx             lam_c  N*nc + ncN
 * Multipliers, CasADi's convention (the Lagrangian is cost + sum pi_k'(E_k w_k + e_k - x_{k+1})
 * + lam_c'(C w) + lam_w' w; lam > 0 where an upper bound is active, < 0 where a lower bound is):
 * at the solution  H w + g + [E' pi - pi shifted] + C' lam_c + lam_w = 0 stage by stage. lam_w of x_0
 * is the multiplier of the fixed initial state.
 * Convexity: the QP's reduced Hessian (on the null space of the dynamics with x_0 fixed) must be positive
 * definite, e.g. every control with curvature or a bound; the blocks H_k themselves may be indefinite (an
 * exact Hessian). Otherwise the Riccati factorisation fails (status OCPQP_FACTORIZATION: a control block
 * that is not positive definite) or the iteration does not converge (OCPQP_MAX_ITER), unless the iterate
 * ends at a vertex where the barrier terms make the Newton matrices positive definite: then a local
 * minimiser (that vertex) is returned with OCPQP_OK.
 * Notes (ocp_qp.c): nu = 0 is supported (the recursion is then the state propagation). An equality
 * lc = uc (or lbw = ubw) is two inequalities. On OCPQP_BAD_DIMS, OCPQP_NONFINITE (in the data) and
 * OCPQP_INFEASIBLE (lb > ub) the outputs are not written. Compiling ocp_qp.c with -DOCPQP_NX=nx
 * -DOCPQP_NU=nu -DOCPQP_NC=nc -DOCPQP_NCN=ncN makes those dimensions compile-time constants (faster;
 * ocpqp_create then returns NULL for any other dimensions).
 */
#ifndef AEV_OCP_QP_H
#define AEV_OCP_QP_H

#ifdef __cplusplus
extern "C" {
#endif

#define OCPQP_INF 1e19

enum {
  OCPQP_OK = 0,             /* converged to the tolerances */
  OCPQP_MAX_ITER = 1,       /* iteration limit reached (the returned point is the last iterate) */
  OCPQP_FACTORIZATION = 2,  /* a Riccati block was not positive definite (a non-convex QP) */
  OCPQP_NONFINITE = 3,      /* a non-finite number in the data or the iterates */
  OCPQP_INFEASIBLE = 4,     /* inconsistent bounds (lb > ub; HPIPM: also its INCONS_EQ) */
  OCPQP_BAD_DIMS = 5,
  OCPQP_ACCEPTABLE = 6      /* not converged (iteration limit or breakdown), but an earlier iterate had every
                             * residual within OCPQP_ACCEPT_FACTOR (100) times its tolerance: that iterate is
                             * returned, with its residuals (ocp_qp.c) */
};

typedef struct { int N, nx, nu, nc, ncN; } ocpqp_dims;

typedef struct {
  int max_iter;        /* default 50 */
  double tol_stat;     /* stationarity residual (inf-norm), default 1e-10 */
  double tol_eq;       /* dynamics residual, default 1e-10 */
  double tol_ineq;     /* inequality residual, default 1e-10 */
  double tol_comp;     /* complementarity (mean), default 1e-10 */
  double reg_prim;     /* static primal regularisation added to R in the Riccati factorisation, default 1e-12 */
} ocpqp_settings;

typedef struct {
  const double *H, *g, *E, *e, *C, *lc, *uc, *lbw, *ubw, *x0;
} ocpqp_data;

typedef struct {
  int iterations;
  int status;
  double res_stat, res_eq, res_ineq, res_comp;  /* final residuals (inf-norm; comp: mean) */
} ocpqp_info;

typedef struct ocpqp_solver ocpqp_solver;

void ocpqp_default_settings(ocpqp_settings *s);
/* All memory of the solver, allocated once; NULL if out of memory or dims invalid (N >= 1, nx >= 1, nu >= 0,
 * nc >= 0, ncN >= 0). The settings are copied. */
ocpqp_solver *ocpqp_create(const ocpqp_dims *dims, const ocpqp_settings *settings);
void ocpqp_free(ocpqp_solver *s);
/* Solve; outputs may be NULL except w. Returns info->status. Allocates nothing. Not thread-safe per solver. */
int ocpqp_solve(ocpqp_solver *s, const ocpqp_data *d, double *w, double *pi, double *lam_w, double *lam_c,
                ocpqp_info *info);
/* The same QP from a primal-dual guess (warm start; layouts and signs of the outputs): w0 (its x_0 part replaced
 * by x0), pi0, lam_w0, lam_c0, each NULL for zeros. Each inequality side starts at its slack at w0 and its
 * multiplier from lam_w0 / lam_c0, the pair s z lifted to at least OCPQP_WARM_MU (ocp_qp.c). A warm start that
 * fails within OCPQP_WARM_MAX_ITER iterations (OCPQP_MAX_ITER, OCPQP_FACTORIZATION) is followed by the cold
 * solve in the same call (info->iterations counts both). The guess is read before any output is written (it may
 * be the output arrays). A non-finite guess: OCPQP_NONFINITE. The HPIPM backend ignores the guess (a cold start). */
int ocpqp_solve_warm(ocpqp_solver *s, const ocpqp_data *d, const double *w0, const double *pi0, const double *lam_w0,
                     const double *lam_c0, double *w, double *pi, double *lam_w, double *lam_c, ocpqp_info *info);

#ifdef __cplusplus
}
#endif
#endif
