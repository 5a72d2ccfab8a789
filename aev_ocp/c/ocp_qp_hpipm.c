/* ocp_qp_hpipm.c — the second backend of the OCP QP interface ocp_qp.h: the same QP, the same data layout,
 * outputs and status codes, solved by HPIPM's C API (libhpipm.so and its headers as the casadi wheel ships
 * them; hand-written C99 glue, linked with -lhpipm -lblasfeo).
 *
 * What it does: x_0 is eliminated (HPIPM's stage 0 has no states: b_0 += A_0 x0, r_0 += S_0 x0,
 * lg/ug_0 -= C_0x x0), every variable with at least one finite bound side (|value| < OCPQP_INF) is an HPIPM box
 * row (idxbx/idxbu), an absent side is masked (d_ocp_qp_set_lb_mask/ub_mask: its multiplier is zero); the
 * general rows are HPIPM's C x + D u rows. d_ocp_qp_ipm_solve runs with the mode given at creation
 * (SPEED, BALANCE or ROBUST: HPIPM's d_ocp_qp_ipm_arg_set_default) and ocp_qp.h's iteration limit,
 * tolerances and static primal regularisation; no warm start. Outputs in ocp_qp.h's convention (CasADi's:
 * lam = lam_ub - lam_lb; pi of the Lagrangian term pi_k'(E_k w_k + e_k - x_{k+1})); lam_w of x_0 closes the
 * stationarity of x_0, as in ocp_qp.c.
 * Status: HPIPM's SUCCESS -> OCPQP_OK, MAX_ITER -> OCPQP_MAX_ITER, MIN_STEP (no progress) -> OCPQP_MAX_ITER,
 * NAN_SOL -> OCPQP_NONFINITE, INCONS_EQ -> OCPQP_INFEASIBLE; non-finite data -> OCPQP_NONFINITE and
 * lb > ub -> OCPQP_INFEASIBLE before any solve (outputs then not written), as ocp_qp.c. Like ocp_qp.c it does
 * not detect primal infeasibility of consistent bounds: such a QP ends at the iteration limit.
 * Memory: the copy buffers are allocated in ocpqp_hpipm_create; HPIPM's structures there (every variable a box
 * row) and again whenever the pattern of finite bounds changes (the first solve, then only if it changes: the
 * MPC's QPs keep theirs), which is the only allocation in ocpqp_solve (out of memory: OCPQP_BAD_DIMS).
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp_ipm.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_common.h"

#include "ocp_qp.h"

/* The HPIPM mode of ocpqp_hpipm_create (values of ocp_qp_hpipm.h's OCPQP_HPIPM_* = enum hpipm_mode). */
int ocpqp_hpipm_mode_speed(void) { return SPEED; }
int ocpqp_hpipm_mode_balance(void) { return BALANCE; }
int ocpqp_hpipm_mode_robust(void) { return ROBUST; }

#define BIG 1e10 /* the value of a masked (absent) bound side; it never enters the solve */

struct ocpqp_solver {
  ocpqp_dims d;
  ocpqp_settings set;
  int nb;
  struct d_ocp_qp_dim dim;
  struct d_ocp_qp qp;
  struct d_ocp_qp_sol sol;
  struct d_ocp_qp_ipm_arg arg;
  struct d_ocp_qp_ipm_ws ws;
  void *mem;           /* the HPIPM structures' three blocks (dims; qp, sol, arg; ws) */
  int *hnx, *hnu;      /* HPIPM's per-stage dims (N+1) */
  int *idx;            /* (N+1) * nb: box-row indices of the stage, HPIPM order (u first, then x) */
  unsigned char *pat, *newpat;  /* (N+1) * nb: the variables with a finite bound side (box rows), this solve's */
  int mode;
  int *nbx, *nbu;      /* (N+1) */
  double *buf;         /* scratch: matrices and vectors of one stage */
  double *bl, *bu, *ml, *mu;  /* one stage's box bounds and masks */
  double *gml, *gmu;          /* one stage's general-row masks */
  double *u, *x, *pi, *llb, *lub, *llg, *lug;  /* one stage's solution */
};

/* Dimensions this glue refuses (ocpqp_hpipm_create returns NULL): nx = 1 with nx + nu a multiple of 4 (nu = 3,
 * 7, ...). Measured on the casadi 3.7 wheel's libhpipm: the controls of stages 1..N-1 come out wrong even for
 * an unconstrained QP with diagonal R (stage 0, whose x_0 is eliminated, is right), in every mode; every other
 * nx in 1..5 with nu in 0..9 agrees with ocp_qp.c to 1e-9 (tests/test_ocp_qp.py). Cause not found. */
int ocpqp_hpipm_unsupported(const ocpqp_dims *d) { return d->nx == 1 && (d->nx + d->nu) % 4 == 0; }

static size_t align8(size_t n) { return (n + 63) & ~(size_t)63; }

static int finite_bound(double v) { return isfinite(v) && fabs(v) < OCPQP_INF; }

/* The HPIPM structures for the box rows of the pattern s->pat (1: the variable has a finite side); the old ones
 * are freed first. 0 on success, -1 out of memory. */
static void release_hpipm(ocpqp_solver *s) {
  if (s->mem) {
    void **b = (void **)s->mem;
    free(b[0]); free(b[1]); free(b[2]); free(b);
    s->mem = NULL;
  }
}

static int build_hpipm(ocpqp_solver *s) {
  const int N = s->d.N, nx = s->d.nx, nb = s->nb;
  int k, i;
  release_hpipm(s);
  void **blocks = (void **)calloc(3, sizeof(void *));
  if (!blocks) return -1;
  s->mem = blocks;
  blocks[0] = malloc(align8(d_ocp_qp_dim_memsize(N)));
  if (!blocks[0]) return -1;
  d_ocp_qp_dim_create(N, &s->dim, blocks[0]);
  for (k = 0; k <= N; ++k) {
    const unsigned char *pk = s->pat + (size_t)k * nb;
    int *ix = s->idx + (size_t)k * nb;
    s->nbu[k] = s->nbx[k] = 0;
    for (i = 0; i < s->hnu[k]; ++i) if (pk[nx + i]) ix[s->nbu[k]++] = i;
    for (i = 0; i < s->hnx[k]; ++i) if (pk[i]) ix[s->nbu[k] + s->nbx[k]++] = i;
    d_ocp_qp_dim_set_nx(k, s->hnx[k], &s->dim);
    d_ocp_qp_dim_set_nu(k, s->hnu[k], &s->dim);
    d_ocp_qp_dim_set_nbx(k, s->nbx[k], &s->dim);
    d_ocp_qp_dim_set_nbu(k, s->nbu[k], &s->dim);
    d_ocp_qp_dim_set_ng(k, k < N ? s->d.nc : s->d.ncN, &s->dim);
    d_ocp_qp_dim_set_ns(k, 0, &s->dim);
  }
  size_t sz_qp = align8(d_ocp_qp_memsize(&s->dim)), sz_sol = align8(d_ocp_qp_sol_memsize(&s->dim));
  size_t sz_arg = align8(d_ocp_qp_ipm_arg_memsize(&s->dim));
  char *m = (char *)malloc(sz_qp + sz_sol + sz_arg);
  if (!m) return -1;
  blocks[1] = m;
  d_ocp_qp_create(&s->dim, &s->qp, m);
  d_ocp_qp_sol_create(&s->dim, &s->sol, m + sz_qp);
  d_ocp_qp_ipm_arg_create(&s->dim, &s->arg, m + sz_qp + sz_sol);
  d_ocp_qp_ipm_arg_set_default((enum hpipm_mode)s->mode, &s->arg);
  int it = s->set.max_iter, ws0 = 0;
  d_ocp_qp_ipm_arg_set_iter_max(&it, &s->arg);
  d_ocp_qp_ipm_arg_set_tol_stat(&s->set.tol_stat, &s->arg);
  d_ocp_qp_ipm_arg_set_tol_eq(&s->set.tol_eq, &s->arg);
  d_ocp_qp_ipm_arg_set_tol_ineq(&s->set.tol_ineq, &s->arg);
  d_ocp_qp_ipm_arg_set_tol_comp(&s->set.tol_comp, &s->arg);
  d_ocp_qp_ipm_arg_set_reg_prim(&s->set.reg_prim, &s->arg);
  d_ocp_qp_ipm_arg_set_warm_start(&ws0, &s->arg);
  blocks[2] = malloc(align8(d_ocp_qp_ipm_ws_memsize(&s->dim, &s->arg)));
  if (!blocks[2]) return -1;
  d_ocp_qp_ipm_ws_create(&s->dim, &s->arg, &s->ws, blocks[2]);
  /* box-row indices: HPIPM's idxbu/idxbx are stage-local (u: 0..nu-1, x: 0..nx-1) */
  for (k = 0; k <= N; ++k) {
    int *ix = s->idx + (size_t)k * nb;
    if (s->nbu[k]) d_ocp_qp_set_idxbu(k, ix, &s->qp);
    if (s->nbx[k]) d_ocp_qp_set_idxbx(k, ix + s->nbu[k], &s->qp);
  }
  return 0;
}

ocpqp_solver *ocpqp_hpipm_create(const ocpqp_dims *dims, const ocpqp_settings *settings, int mode) {
  if (!dims || dims->N < 1 || dims->nx < 1 || dims->nu < 0 || dims->nc < 0 || dims->ncN < 0) return NULL;
  if (mode != SPEED && mode != BALANCE && mode != ROBUST && mode != SPEED_ABS) return NULL;
  if (ocpqp_hpipm_unsupported(dims)) return NULL;
  ocpqp_solver *s = (ocpqp_solver *)calloc(1, sizeof(ocpqp_solver));
  if (!s) return NULL;
  int N = dims->N, nx = dims->nx, nu = dims->nu, nb = nx + nu, k;
  int ngmax = dims->nc > dims->ncN ? dims->nc : dims->ncN;
  s->d = *dims;
  s->mode = mode;
  if (settings) s->set = *settings; else ocpqp_default_settings(&s->set);
  s->nb = nb;
  s->hnx = (int *)calloc((size_t)(N + 1), sizeof(int));
  s->hnu = (int *)calloc((size_t)(N + 1), sizeof(int));
  s->nbx = (int *)calloc((size_t)(N + 1), sizeof(int));
  s->nbu = (int *)calloc((size_t)(N + 1), sizeof(int));
  s->idx = (int *)calloc((size_t)(N + 1) * (size_t)nb, sizeof(int));
  s->pat = (unsigned char *)calloc((size_t)(N + 1) * (size_t)nb, 1);
  s->newpat = (unsigned char *)calloc((size_t)(N + 1) * (size_t)nb, 1);
  size_t nbuf = (size_t)nb * nb + (size_t)ngmax * nb + (size_t)nx * nb + 4 * (size_t)nb + 2 * (size_t)ngmax;
  s->buf = (double *)calloc(nbuf, sizeof(double));
  s->bl = (double *)calloc((size_t)nb * 4, sizeof(double));
  s->u = (double *)calloc((size_t)(nb * 5 + 4 * ngmax + 2), sizeof(double));
  if (!s->hnx || !s->hnu || !s->nbx || !s->nbu || !s->idx || !s->pat || !s->newpat || !s->buf || !s->bl || !s->u) {
    ocpqp_free(s);
    return NULL;
  }
  s->bu = s->bl + nb; s->ml = s->bu + nb; s->mu = s->ml + nb;
  s->x = s->u + nb; s->pi = s->x + nb; s->llb = s->pi + nb; s->lub = s->llb + nb; s->llg = s->lub + nb;
  s->lug = s->llg + ngmax + 1;
  s->gml = s->lug + ngmax + 1; s->gmu = s->gml + ngmax;
  for (k = 0; k <= N; ++k) { s->hnx[k] = k == 0 ? 0 : nx; s->hnu[k] = k < N ? nu : 0; }
  /* every variable a box row until the first solve shows which have a finite side */
  memset(s->pat, 1, (size_t)(N + 1) * (size_t)nb);
  if (build_hpipm(s) != 0) { ocpqp_free(s); return NULL; }
  return s;
}

ocpqp_solver *ocpqp_create(const ocpqp_dims *dims, const ocpqp_settings *settings) {
  return ocpqp_hpipm_create(dims, settings, BALANCE);
}

void ocpqp_default_settings(ocpqp_settings *s) {
  s->max_iter = 50;
  s->tol_stat = s->tol_eq = s->tol_ineq = s->tol_comp = 1e-10;
  s->reg_prim = 1e-12;
}

void ocpqp_free(ocpqp_solver *s) {
  if (!s) return;
  release_hpipm(s);
  free(s->hnx); free(s->hnu); free(s->nbx); free(s->nbu); free(s->idx); free(s->pat); free(s->newpat);
  free(s->buf); free(s->bl); free(s->u);
  free(s);
}

/* one side of a box row: value (BIG-clipped) and mask */
static void side(double v, double sign, double *val, double *mask) {
  if (finite_bound(v)) { *val = v; *mask = 1.0; } else { *val = sign * BIG; *mask = 0.0; }
}

int ocpqp_solve(ocpqp_solver *s, const ocpqp_data *d, double *w, double *pi, double *lam_w, double *lam_c,
                ocpqp_info *info) {
  ocpqp_info dummy;
  if (!info) info = &dummy;
  memset(info, 0, sizeof(*info));
  if (!s || !d || !w) { info->status = OCPQP_BAD_DIMS; return info->status; }
  const int N = s->d.N, nx = s->d.nx, nu = s->d.nu, nc = s->d.nc, ncN = s->d.ncN, nb = s->nb;
  const size_t nw = (size_t)N * nb + nx;
  size_t i, j;
  int k;
  /* checks as ocp_qp.c: non-finite data, crossed bounds */
  {
    size_t nH = (size_t)N * nb * nb + (size_t)nx * nx, nE = (size_t)N * nx * nb, nC = (size_t)N * nc * nb + (size_t)ncN * nx;
    size_t nr = (size_t)N * nc + ncN;
    for (i = 0; i < nH; ++i) if (!isfinite(d->H[i])) { info->status = OCPQP_NONFINITE; return info->status; }
    for (i = 0; i < nw; ++i) if (!isfinite(d->g[i])) { info->status = OCPQP_NONFINITE; return info->status; }
    for (i = 0; i < nE; ++i) if (!isfinite(d->E[i])) { info->status = OCPQP_NONFINITE; return info->status; }
    for (i = 0; i < (size_t)N * nx; ++i) if (!isfinite(d->e[i])) { info->status = OCPQP_NONFINITE; return info->status; }
    for (i = 0; i < nC; ++i) if (!isfinite(d->C[i])) { info->status = OCPQP_NONFINITE; return info->status; }
    for (i = 0; i < (size_t)nx; ++i) if (!isfinite(d->x0[i])) { info->status = OCPQP_NONFINITE; return info->status; }
    for (i = 0; i < nw; ++i) {
      double lo = d->lbw[i], up = d->ubw[i];
      if (isnan(lo) || isnan(up)) { info->status = OCPQP_NONFINITE; return info->status; }
      if (i >= (size_t)nx && lo > up && finite_bound(lo) && finite_bound(up)) { info->status = OCPQP_INFEASIBLE; return info->status; }
    }
    for (i = 0; i < nr; ++i) {
      double lo = d->lc[i], up = d->uc[i];
      if (isnan(lo) || isnan(up)) { info->status = OCPQP_NONFINITE; return info->status; }
      if (lo > up && finite_bound(lo) && finite_bound(up)) { info->status = OCPQP_INFEASIBLE; return info->status; }
    }
  }
  /* the box rows: the variables with a finite side; HPIPM's structures are rebuilt when that changes */
  for (k = 0; k <= N; ++k) {
    const int n = k < N ? nb : nx;
    for (j = 0; j < (size_t)nb; ++j) {
      size_t q = (size_t)k * nb + j;
      s->newpat[q] = (unsigned char)(k > 0 || j >= (size_t)nx ? (j < (size_t)n && (finite_bound(d->lbw[q]) || finite_bound(d->ubw[q]))) : 0);
    }
  }
  if (memcmp(s->newpat, s->pat, (size_t)(N + 1) * (size_t)nb) != 0) {
    memcpy(s->pat, s->newpat, (size_t)(N + 1) * (size_t)nb);
    if (build_hpipm(s) != 0) { info->status = OCPQP_BAD_DIMS; return info->status; }  /* out of memory */
  }
  double *M = s->buf;                       /* nb*nb */
  double *G = M + (size_t)nb * nb;          /* ngmax*nb */
  int ngmax = nc > ncN ? nc : ncN;
  double *AB = G + (size_t)ngmax * nb;      /* nx*nb */
  double *v1 = AB + (size_t)nx * nb, *v2 = v1 + nb, *gl = v2 + 2 * nb, *gu = gl + ngmax;
  const double *x0 = d->x0;
  for (k = 0; k <= N; ++k) {
    const int n = k < N ? nb : nx, m = k < N ? nc : ncN, kx = k == 0 ? 0 : nx, ku = k < N ? nu : 0;
    const double *H = d->H + (size_t)k * nb * nb, *g = d->g + (size_t)k * nb;
    const double *C = d->C + (size_t)k * nc * nb, *lc = d->lc + (size_t)k * nc, *uc = d->uc + (size_t)k * nc;
    const double *lb = d->lbw + (size_t)k * nb, *ub = d->ubw + (size_t)k * nb;
    int a, b;
    /* cost: Q (x block), S (u x), R (u block); q, r (stage 0: x0 folded into r) */
    /* (matrices first, then the vectors: HPIPM keeps r and q in the last row of one RSQrq matrix) */
    if (kx) {
      for (b = 0; b < nx; ++b) for (a = 0; a < nx; ++a) M[(size_t)b * nx + a] = H[(size_t)b * n + a];
      d_ocp_qp_set_Q(k, M, &s->qp);
    }
    if (ku) {
      for (b = 0; b < nu; ++b) for (a = 0; a < nu; ++a) M[(size_t)b * nu + a] = H[(size_t)(nx + b) * n + nx + a];
      d_ocp_qp_set_R(k, M, &s->qp);
      if (kx) {
        for (b = 0; b < nx; ++b) for (a = 0; a < nu; ++a) M[(size_t)b * nu + a] = H[(size_t)b * n + nx + a];
        d_ocp_qp_set_S(k, M, &s->qp);
      }
      for (a = 0; a < nu; ++a) {
        double r = g[nx + a];
        if (k == 0) for (b = 0; b < nx; ++b) r += H[(size_t)b * n + nx + a] * x0[b];
        v1[a] = r;
      }
      d_ocp_qp_set_r(k, v1, &s->qp);
    }
    if (kx) d_ocp_qp_set_q(k, (double *)g, &s->qp);
    /* dynamics: A (x), B (u), b (stage 0: + A x0) */
    if (k < N) {
      const double *E = d->E + (size_t)k * nx * nb, *e = d->e + (size_t)k * nx;
      if (kx) d_ocp_qp_set_A(k, (double *)E, &s->qp);
      if (nu) d_ocp_qp_set_B(k, (double *)(E + (size_t)nx * nx), &s->qp);
      for (a = 0; a < nx; ++a) {
        double bv = e[a];
        if (k == 0) for (b = 0; b < nx; ++b) bv += E[(size_t)b * nx + a] * x0[b];
        v2[a] = bv;
      }
      d_ocp_qp_set_b(k, v2, &s->qp);
    }
    /* general rows: C (x), D (u); stage 0: bounds shifted by C_x x0 */
    if (m) {
      const double *Ck = k < N ? C : d->C + (size_t)N * nc * nb;
      const double *lck = k < N ? lc : d->lc + (size_t)N * nc, *uck = k < N ? uc : d->uc + (size_t)N * nc;
      double *ml = s->gml, *mu = s->gmu;
      for (a = 0; a < m; ++a) {
        double shift = 0.0;
        if (k == 0) for (b = 0; b < nx; ++b) shift += Ck[(size_t)b * m + a] * x0[b];
        side(lck[a], -1.0, gl + a, ml + a);
        side(uck[a], 1.0, gu + a, mu + a);
        if (ml[a] > 0) gl[a] -= shift;
        if (mu[a] > 0) gu[a] -= shift;
      }
      if (kx) d_ocp_qp_set_C(k, (double *)Ck, &s->qp);
      if (ku) d_ocp_qp_set_D(k, (double *)(Ck + (size_t)nx * m), &s->qp);
      d_ocp_qp_set_lg(k, gl, &s->qp);
      d_ocp_qp_set_ug(k, gu, &s->qp);
      d_ocp_qp_set_lg_mask(k, ml, &s->qp);
      d_ocp_qp_set_ug_mask(k, mu, &s->qp);
    }
    /* boxes: HPIPM orders the stage's box rows u first, then x (the variables with a finite side); an absent
     * side is masked */
    if (s->nbu[k] + s->nbx[k]) {
      const int *ix = s->idx + (size_t)k * nb, nbu = s->nbu[k];
      for (a = 0; a < nbu; ++a) {
        side(lb[nx + ix[a]], -1.0, s->bl + a, s->ml + a);
        side(ub[nx + ix[a]], 1.0, s->bu + a, s->mu + a);
      }
      for (a = 0; a < s->nbx[k]; ++a) {
        side(lb[ix[nbu + a]], -1.0, s->bl + nbu + a, s->ml + nbu + a);
        side(ub[ix[nbu + a]], 1.0, s->bu + nbu + a, s->mu + nbu + a);
      }
      d_ocp_qp_set_lb(k, s->bl, &s->qp);
      d_ocp_qp_set_ub(k, s->bu, &s->qp);
      d_ocp_qp_set_lb_mask(k, s->ml, &s->qp);
      d_ocp_qp_set_ub_mask(k, s->mu, &s->qp);
    }
  }
  d_ocp_qp_ipm_solve(&s->qp, &s->sol, &s->arg, &s->ws);
  int hst = 0, iter = 0;
  d_ocp_qp_ipm_get_status(&s->ws, &hst);
  d_ocp_qp_ipm_get_iter(&s->ws, &iter);
  d_ocp_qp_ipm_get_max_res_stat(&s->ws, &info->res_stat);
  d_ocp_qp_ipm_get_max_res_eq(&s->ws, &info->res_eq);
  d_ocp_qp_ipm_get_max_res_ineq(&s->ws, &info->res_ineq);
  d_ocp_qp_ipm_get_max_res_comp(&s->ws, &info->res_comp);
  info->iterations = iter;
  info->status = hst == SUCCESS ? OCPQP_OK : hst == NAN_SOL ? OCPQP_NONFINITE
               : hst == INCONS_EQ ? OCPQP_INFEASIBLE : OCPQP_MAX_ITER;  /* MAX_ITER, MIN_STEP */
  /* outputs */
  for (k = 0; k <= N; ++k) {
    const int kx = k == 0 ? 0 : nx, ku = k < N ? nu : 0, m = k < N ? nc : ncN;
    double *wk = w + (size_t)k * nb;
    int a;
    if (k == 0) memcpy(wk, x0, (size_t)nx * sizeof(double));
    else d_ocp_qp_sol_get_x(k, &s->sol, wk);
    if (ku) d_ocp_qp_sol_get_u(k, &s->sol, wk + nx);
    if (pi && k < N) {
      d_ocp_qp_sol_get_pi(k, &s->sol, s->pi);
      for (a = 0; a < nx; ++a) pi[(size_t)k * nx + a] = s->pi[a];  /* HPIPM: the same sign */
    }
    if (lam_w) {
      const int *ix = s->idx + (size_t)k * nb, nbu = s->nbu[k];
      for (a = 0; a < kx + ku; ++a) lam_w[(size_t)k * nb + (k == 0 ? nx : 0) + a] = 0.0;  /* no box row: 0 */
      if (nbu + s->nbx[k]) {
        d_ocp_qp_sol_get_lam_lb(k, &s->sol, s->llb);
        d_ocp_qp_sol_get_lam_ub(k, &s->sol, s->lub);
        for (a = 0; a < nbu; ++a) lam_w[(size_t)k * nb + nx + ix[a]] = s->lub[a] - s->llb[a];
        for (a = 0; a < s->nbx[k]; ++a) lam_w[(size_t)k * nb + ix[nbu + a]] = s->lub[nbu + a] - s->llb[nbu + a];
      }
    }
    if (lam_c && m) {
      d_ocp_qp_sol_get_lam_lg(k, &s->sol, s->llg);
      d_ocp_qp_sol_get_lam_ug(k, &s->sol, s->lug);
      for (a = 0; a < m; ++a) lam_c[(size_t)k * nc + a] = s->lug[a] - s->llg[a];
    }
  }
  if (lam_w) {
    /* x_0 is fixed: its multiplier closes its stationarity
     * H_0xx x0 + H_0xu u0 + g_0x + A_0' pi_0 + C_0x' lam_c0 + lam_x0 = 0 */
    const double *H = d->H, *E = d->E;
    for (i = 0; i < (size_t)nx; ++i) {
      double r = d->g[i];
      for (j = 0; j < (size_t)nb; ++j) r += H[i * nb + j] * w[j];  /* symmetric: row i = column i */
      if (pi) for (j = 0; j < (size_t)nx; ++j) r += E[i * nx + j] * pi[j];
      if (lam_c) for (j = 0; j < (size_t)nc; ++j) r += d->C[i * nc + j] * lam_c[j];
      lam_w[i] = -r;
    }
  }
  return info->status;
}

/* ocp_qp.h's warm start: the guess is ignored here (HPIPM starts cold, as ocpqp_solve) */
int ocpqp_solve_warm(ocpqp_solver *s, const ocpqp_data *d, const double *w0, const double *pi0, const double *lam_w0,
                     const double *lam_c0, double *w, double *pi, double *lam_w, double *lam_c, ocpqp_info *info) {
  (void)w0; (void)pi0; (void)lam_w0; (void)lam_c0;
  return ocpqp_solve(s, d, w, pi, lam_w, lam_c, info);
}
