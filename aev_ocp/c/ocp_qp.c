/* ocp_qp.c — structure-exploiting interior-point QP solver of aev_ocp (hand-written C99; see ocp_qp.h), the
 * default backend of the ocp_qp.h interface (the other: ocp_qp_hpipm.c). It does not detect primal
 * infeasibility: only inconsistent bounds (lb > ub, checked before the solve) give OCPQP_INFEASIBLE.
 *
 * Inequalities. Every bound of w and every general row C w is a "row" (stage k < N: nb bound rows then
 * nc general rows; stage N: nx bound rows then ncN general rows). Each finite side of a row is a "side"
 * i with sign sg_i = +1 (lower bound b_i) or -1 (upper bound b_i), slack s_i = sg_i (d_row - b_i) >= 0
 * and multiplier z_i >= 0; the row's CasADi multiplier is lam_row = sum over its sides of -sg_i z_i.
 *
 * Newton system (residuals r_stat = H w + g + E'pi - pi shifted + D' lam, r_eq_k = E_k w_k + e_k -
 * x_{k+1}, r_i = sg_i (d_i - b_i) - s_i, rc_i = s_i z_i (- sigma mu + corrector)): eliminating ds, dz
 * gives, stage by stage, the equality-constrained QP
 *     min 1/2 dw' M dw + gt' dw  s.t.  dx_{k+1} = E_k dw_k + r_eq_k,  dx_0 = 0,
 * with M = H + D' diag(z/s) D and gt = r_stat + D' q, q_row = sum sg_i (rc_i + z_i r_i) / s_i, solved by
 * the Riccati recursion in square-root form (value function 1/2 x'P x + p'x with P = Lp Lp', so the
 * Newton matrices stay PSD under rounding when the barrier terms are large; dpi_k = P_{k+1} dx_{k+1} + p_{k+1}), then
 * ds_i = sg_i dd_row + r_i and dz_i = -(rc_i + z_i ds_i) / s_i. A P_k that is indefinite (indefinite
 * Hessian blocks, an exact Hessian, with a positive definite reduced Hessian) has no square root: the
 * stage before then adds E_k' P_k E_k explicitly (only the control blocks L_k must be positive definite).
 * The factorisation (M, P_k, the Cholesky factor L_k of the control block and Y_k = L_k^{-1} G_ux) is
 * done once per iteration; the right-hand-side recursion runs twice (predictor, corrector), and again
 * (iterative refinement, at most 4 times) when the barrier terms z/s are so large that the reduced
 * solve's rounding would show in the stationarity residual (late iterations).
 * Start: w = 0 with x_0 = x0, pi = 0, s = max(slack, 1), z = 2 sqrt(max(1, |g|inf)) / s^(1/4); or, warm
 * (ocpqp_solve_warm), the guess with its pairs s z lifted to >= OCPQP_WARM_MU. One step length for
 * primal and dual variables, fraction to the boundary 0.995 (warm: max(0.995, 1 - mu)), centring
 * sigma = (mu_aff / mu)^3. Two
 * safeguards against the stall of plain Mehrotra on degenerate rows (below): the wide-neighbourhood step
 * rule (neighbourhood_step, every iteration) and Gondzio's centrality correctors (correct_centrality, in the
 * end game, once the residuals are below mu).
 * Termination: every residual (inf-norms, complementarity as the mean of s z) below its tolerance. On
 * degenerate rows (weakly active, or linearly dependent active rows) w is then O(sqrt(mean s z)) from the
 * exact solution, e.g. up to 1e-4 at tolerances 1e-9 on the MPC's QPs, 4e-8 at 1e-12 (tests/test_ocp_qp.py).
 * Speed (the MPC's QPs are small: nx 5-6, nu 1-3): the work is done stage by stage in small kernels (see
 * "kernels" below), each stage's rows and sides inside its own pass; long reductions over the sides keep four
 * partial results (their addition chains, not the arithmetic, bounded those loops). Against the previous
 * version (generic matrix-vector loops, one sweep per piece): about 0.76x the time on the canonical MPC's QPs
 * (N = 40, nx 5, nu 1), 0.85x on the traffic MPC's (N = 25, nx 6, nu 3), the same iterates up to rounding
 * (benchmarks/bench_ocp_qp.py --baseline-src compares two versions in one process).
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "ocp_qp.h"

#if defined(OCPQP_NX) && defined(OCPQP_NU) && defined(OCPQP_NC) && defined(OCPQP_NCN) && defined(__GNUC__)
#define UNROLL _Pragma("GCC unroll 16") /* every loop of a block: its trip count is a constant */
#else
#define UNROLL
#endif
#define AMAX(acc, v) do { double a_ = fabs(v); if (a_ > (acc)) (acc) = a_; } while (0)

/* Dimensions. Compiled with -DOCPQP_NX=.. -DOCPQP_NU=.. -DOCPQP_NC=.. -DOCPQP_NCN=.. (all four) they are
 * compile-time constants (the small loops are then unrolled and vectorised: about 1.3x faster) and
 * ocpqp_create accepts only those; otherwise they are the run-time values of ocpqp_create. */
#if defined(OCPQP_NX) && defined(OCPQP_NU) && defined(OCPQP_NC) && defined(OCPQP_NCN)
#define OCPQP_FIXED_DIMS 1
#define DNX(s) (OCPQP_NX)
#define DNU(s) (OCPQP_NU)
#define DNC(s) (OCPQP_NC)
#define DNCN(s) (OCPQP_NCN)
#define DNB(s) (OCPQP_NX + OCPQP_NU)
#else
#define OCPQP_FIXED_DIMS 0
#define DNX(s) ((s)->d.nx)
#define DNU(s) ((s)->d.nu)
#define DNC(s) ((s)->d.nc)
#define DNCN(s) ((s)->d.ncN)
#define DNB(s) ((s)->nb)
#endif

struct ocpqp_solver {
  ocpqp_dims d;
  ocpqp_settings set;
  int nb, nw, nrow, nside_max;
  /* factorisation */
  double *P;      /* (N+1) nx x nx: lower Cholesky factors Lp_k of the Riccati matrices P_k */
  double *Pf;     /* (N+1) nx x nx: the P_k themselves (both triangles; for the right-hand sides) */
  double *L;      /* N nu x nu (lower Cholesky factor of the control block) */
  double *Ld;     /* N nu: inverses of L's diagonal */
  double *Y;      /* N nu x nx (L^{-1} G_ux) */
  double *G;      /* nb x nb work */
  double *ET, *CT; /* the data's E_k' (nb x nx) and C_k' (nb x nc, then nx x ncN), copied per solve */
  double *F;      /* nb x (nx + nc) work ([E_k' Lp_{k+1}, C_k' sqrt(sig)]) */
  /* right-hand side recursion */
  double *p;      /* (N+1) nx */
  double *ell;    /* N nu */
  double *h;      /* nb work */
  double *t;      /* nx work */
  /* iterate and steps */
  double *w, *pi, *dw, *dpi;
  double *rstat, *req;
  double *drow, *ddrow, *sigrow, *qrow, *lamrow;
  double *s, *z, *b, *sg, *r, *rc, *ds, *dz;
  double *is;     /* 1/s of the current factorisation */
  double *dw2, *dpi2, *ds2, *dz2, *rho, *lamrow2;  /* iterative refinement */
  double *bw, *bpi, *blam, *brs;  /* the best acceptable iterate: w, pi, lamrow, rstat (see OCPQP_ACCEPT_FACTOR) */
  int *srow;
  int *pind;      /* N+1: P_k is indefinite (no square root; the stage before adds E' P_k E explicitly) */
  int *kside;     /* N+2: the sides of stage k are kside[k] .. kside[k+1] - 1 */
  int nside;
  double sigmax;  /* largest barrier term z/s of the current factorisation */
};

void ocpqp_default_settings(ocpqp_settings *s) {
  s->max_iter = 50;
  s->tol_stat = 1e-10;
  s->tol_eq = 1e-10;
  s->tol_ineq = 1e-10;
  s->tol_comp = 1e-10;
  s->reg_prim = 1e-12;
}

/* Lay the solver's arrays out in blk (NULL: only count); returns the number of doubles. */
static size_t layout(ocpqp_solver *s, double *blk) {
  size_t N = (size_t)s->d.N, nx = (size_t)s->d.nx, nu = (size_t)s->d.nu, nb = nx + nu;
  size_t nc = (size_t)s->d.nc, ncN = (size_t)s->d.ncN, nw = (size_t)s->nw, nrow = (size_t)s->nrow;
  size_t nsm = (size_t)s->nside_max, off = 0, i;
  double **per_nw[] = {&s->w, &s->dw, &s->rstat, &s->dw2, &s->rho, &s->bw, &s->brs};
  double **per_pi[] = {&s->pi, &s->dpi, &s->req, &s->dpi2, &s->bpi};
  double **per_row[] = {&s->drow, &s->ddrow, &s->sigrow, &s->qrow, &s->lamrow, &s->lamrow2, &s->blam};
  double **per_side[] = {&s->s, &s->z, &s->b, &s->sg, &s->r, &s->rc, &s->ds, &s->dz, &s->is, &s->ds2, &s->dz2};
#define TAKE(ptr, n) do { (ptr) = blk ? blk + off : NULL; off += (n); } while (0)
  TAKE(s->P, (N + 1) * nx * nx);
  TAKE(s->Pf, (N + 1) * nx * nx);
  TAKE(s->L, N * nu * nu);
  TAKE(s->Y, N * nu * nx);
  TAKE(s->Ld, N * nu);
  TAKE(s->G, nb * nb);
  TAKE(s->F, nb * (nx + nc + ncN));
  TAKE(s->ET, N * nb * nx);
  TAKE(s->CT, N * nb * nc + nx * ncN);
  TAKE(s->p, (N + 1) * nx);
  TAKE(s->ell, N * nu);
  TAKE(s->h, nb);
  TAKE(s->t, nx);
  for (i = 0; i < sizeof per_nw / sizeof *per_nw; ++i) TAKE(*per_nw[i], nw);
  for (i = 0; i < sizeof per_pi / sizeof *per_pi; ++i) TAKE(*per_pi[i], N * nx);
  for (i = 0; i < sizeof per_row / sizeof *per_row; ++i) TAKE(*per_row[i], nrow);
  for (i = 0; i < sizeof per_side / sizeof *per_side; ++i) TAKE(*per_side[i], nsm);
#undef TAKE
  return off;
}

ocpqp_solver *ocpqp_create(const ocpqp_dims *dims, const ocpqp_settings *settings) {
  ocpqp_solver probe, *s;
  size_t nd, head = (sizeof(ocpqp_solver) + sizeof(double) - 1) / sizeof(double);
  double *blk;
  if (!dims || dims->N < 1 || dims->nx < 1 || dims->nu < 0 || dims->nc < 0 || dims->ncN < 0) return NULL;
#if OCPQP_FIXED_DIMS
  if (dims->nx != OCPQP_NX || dims->nu != OCPQP_NU || dims->nc != OCPQP_NC || dims->ncN != OCPQP_NCN) return NULL;
#endif
  memset(&probe, 0, sizeof probe);
  probe.d = *dims;
  probe.nb = dims->nx + dims->nu;
  probe.nw = dims->N * probe.nb + dims->nx;
  probe.nrow = dims->N * (probe.nb + dims->nc) + dims->nx + dims->ncN;
  probe.nside_max = 2 * probe.nrow;
  if (settings) probe.set = *settings; else ocpqp_default_settings(&probe.set);
  nd = layout(&probe, NULL);
  /* one block: the struct, the doubles, then the side -> row indices */
  blk = (double *)malloc((head + nd) * sizeof(double) + (size_t)(probe.nside_max + 2 * dims->N + 3) * sizeof(int));
  if (!blk) return NULL;
  s = (ocpqp_solver *)(void *)blk;
  *s = probe;
  blk += head;
  memset(blk, 0, nd * sizeof(double));
  layout(s, blk);
  s->srow = (int *)(void *)(blk + nd);
  s->pind = s->srow + s->nside_max;
  s->kside = s->pind + dims->N + 1;
  return s;
}

void ocpqp_free(ocpqp_solver *s) { free(s); }

/* ------------------------------------------------------------------------------------------ kernels */
/* The stage kernels below are written for small blocks: every product is a dot product accumulated in a
 * register (no partial sums stored and reloaded), every block pointer is restrict, and each kernel is
 * inlined into its caller, where the block sizes (nb, nx, nc, or nx, ncN at stage N) are the arguments: with
 * the dimensions compile-time constants (-DOCPQP_NX=..) every loop then has a constant trip count and is
 * unrolled. The stages' inequality sides are contiguous (s->kside), so each stage's rows are handled inside
 * the stage's pass instead of in separate sweeps over all rows. */
#if defined(__GNUC__)
#define KERNEL static inline __attribute__((always_inline))
#else
#define KERNEL static inline
#endif

/* Reductions over long vectors keep four partial results: four independent chains of additions (or
 * comparisons) instead of one, whose latency would otherwise bound the loop. */
static int all_finite(const double *x, size_t n) {
  size_t i;
  double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
  for (i = 0; i + 3 < n; i += 4) {  /* NaN if any entry is NaN or +-inf */
    a0 += x[i] * 0.0;
    a1 += x[i + 1] * 0.0;
    a2 += x[i + 2] * 0.0;
    a3 += x[i + 3] * 0.0;
  }
  for (; i < n; ++i) a0 += x[i] * 0.0;
  return (a0 + a1) + (a2 + a3) == 0.0;
}

/* sum over the sides of (s + alpha ds)(z + alpha dz) (alpha 0: of s z, ds and dz not read); *pmin (if not
 * NULL): the smallest of them */
static double pair_sum(const ocpqp_solver *s, double alpha, double *pmin) {
  int i, n = s->nside;
  const double *restrict sl = s->s, *restrict z = s->z, *restrict ds = s->ds, *restrict dz = s->dz;
  double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0, m0 = HUGE_VAL, m1 = HUGE_VAL, m2 = HUGE_VAL, m3 = HUGE_VAL;
#define OCPQP_PAIR(j) (alpha != 0.0 ? (sl[j] + alpha * ds[j]) * (z[j] + alpha * dz[j]) : sl[j] * z[j])
  for (i = 0; i + 3 < n; i += 4) {
    double p0 = OCPQP_PAIR(i), p1 = OCPQP_PAIR(i + 1), p2 = OCPQP_PAIR(i + 2), p3 = OCPQP_PAIR(i + 3);
    a0 += p0; a1 += p1; a2 += p2; a3 += p3;
    m0 = p0 < m0 ? p0 : m0; m1 = p1 < m1 ? p1 : m1; m2 = p2 < m2 ? p2 : m2; m3 = p3 < m3 ? p3 : m3;
  }
  for (; i < n; ++i) {
    double p0 = OCPQP_PAIR(i);
    a0 += p0;
    m0 = p0 < m0 ? p0 : m0;
  }
#undef OCPQP_PAIR
  if (pmin) {
    m0 = m1 < m0 ? m1 : m0;
    m2 = m3 < m2 ? m3 : m2;
    *pmin = m2 < m0 ? m2 : m0;
  }
  return (a0 + a1) + (a2 + a3);
}

static int no_nan(const double *x, size_t n) {
  size_t i;
  for (i = 0; i < n; ++i)
    if (x[i] != x[i]) return 0;
  return 1;
}

/* row values of stage k (n bound rows, m general rows): dr = [w_k; C_k w_k] (Ck m x n column-major) */
KERNEL void stage_rows(int n, int m, const double *restrict Ck, const double *restrict wk, double *restrict dr) {
  int i, j;
  UNROLL for (i = 0; i < n; ++i) dr[i] = wk[i];
  UNROLL for (i = 0; i < m; ++i) {
    double acc = 0.0;
    UNROLL for (j = 0; j < n; ++j) acc += Ck[i + j * m] * wk[j];
    dr[n + i] = acc;
  }
}

/* stationarity of stage k: out = base + D_k' lam_k + H_k w_k + E_k' pi_k - [pi_{k-1}; 0] (base, ETk/pik, pim
 * NULL: left out; n x n Hk, CTk n x m, ETk n x nx column-major) */
KERNEL void stage_stat(int n, int m, int nx, const double *restrict Hk, const double *restrict CTk,
                       const double *restrict ETk, const double *restrict wk, const double *restrict lamk,
                       const double *restrict pik, const double *restrict pim, const double *restrict base,
                       double *restrict out) {
  int i, j;
  UNROLL for (i = 0; i < n; ++i) {
    double acc = base ? base[i] + lamk[i] : lamk[i];
    UNROLL for (j = 0; j < n; ++j) acc += Hk[i + j * n] * wk[j];
    UNROLL for (j = 0; j < m; ++j) acc += CTk[i + j * n] * lamk[n + j];
    if (ETk) {
      UNROLL for (j = 0; j < nx; ++j) acc += ETk[i + j * n] * pik[j];
    }
    if (pim && i < nx) acc -= pim[i];
    out[i] = acc;
  }
}

/* row multipliers of stage k (n + m rows, first row r0) from the stage's sides: lam = sum -sg z */
KERNEL void stage_lam(const ocpqp_solver *s, int k, int nrk, int r0, const double *restrict z, double *restrict lamk) {
  int i;
  UNROLL for (i = 0; i < nrk; ++i) lamk[i] = 0.0;
  for (i = s->kside[k]; i < s->kside[k + 1]; ++i) lamk[s->srow[i] - r0] -= s->sg[i] * z[i];
}

/* ------------------------------------------------------------------------------------------ pieces */
/* row values d = D w (bound rows: w; general rows: C w), every stage */
static void row_values(ocpqp_solver *s, const ocpqp_data *d, const double *w, double *dr) {
  int N = s->d.N, nx = DNX(s), nb = DNB(s), nc = DNC(s), ncN = DNCN(s), nr = nb + nc, k;
  for (k = 0; k < N; ++k) stage_rows(nb, nc, d->C + (size_t)k * nc * nb, w + (size_t)k * nb, dr + (size_t)k * nr);
  stage_rows(nx, ncN, d->C + (size_t)N * nc * nb, w + (size_t)N * nb, dr + (size_t)N * nr);
}

/* out = base + D' lam + H w + E' pi - pi shifted (per stage; lam per row; base not NULL) */
static void stationarity(ocpqp_solver *s, const ocpqp_data *d, const double *w, const double *pi, const double *lam,
                         const double *base, double *out) {
  int N = s->d.N, nx = DNX(s), nb = DNB(s), nc = DNC(s), nr = nb + nc, k;
  for (k = 0; k < N; ++k)
    stage_stat(nb, nc, nx, d->H + (size_t)k * nb * nb, s->CT + (size_t)k * nc * nb, s->ET + (size_t)k * nx * nb,
               w + (size_t)k * nb, lam + (size_t)k * nr, pi + (size_t)k * nx, k ? pi + (size_t)(k - 1) * nx : NULL,
               base + (size_t)k * nb, out + (size_t)k * nb);
  stage_stat(nx, DNCN(s), nx, d->H + (size_t)N * nb * nb, s->CT + (size_t)N * nc * nb, NULL, w + (size_t)N * nb,
             lam + (size_t)N * nr, NULL, pi + (size_t)(N - 1) * nx, base + (size_t)N * nb, out + (size_t)N * nb);
}

/* lam per row = sum over the row's sides of -sg z */
static void row_multipliers(ocpqp_solver *s, const double *z, double *lam) {
  int N = s->d.N, nr = DNB(s) + DNC(s), k;
  for (k = 0; k < N; ++k) stage_lam(s, k, nr, k * nr, z, lam + (size_t)k * nr);
  stage_lam(s, N, DNX(s) + DNCN(s), N * nr, z, lam + (size_t)N * nr);
}

/* the residuals of stage k (n, m: its block sizes) at (w, pi, s, z), their maxima into acc[0..2] */
KERNEL void stage_residuals(ocpqp_solver *s, const ocpqp_data *d, int k, int n, int m, double *acc) {
  int N = s->d.N, nx = DNX(s), nb = DNB(s), nc = DNC(s), nr = nb + nc, i, j;
  const double *restrict wk = s->w + (size_t)k * nb;
  double *restrict lamk = s->lamrow + (size_t)k * nr, *restrict rk = s->rstat + (size_t)k * nb;
  double *restrict dr = s->drow + (size_t)k * nr;
  stage_lam(s, k, n + m, k * nr, s->z, lamk);
  stage_stat(n, m, nx, d->H + (size_t)k * nb * nb, s->CT + (size_t)k * nc * nb,
             k < N ? s->ET + (size_t)k * nx * nb : NULL, wk, lamk, k < N ? s->pi + (size_t)k * nx : NULL,
             k ? s->pi + (size_t)(k - 1) * nx : NULL, d->g + (size_t)k * nb, rk);
  UNROLL for (i = k ? 0 : nx; i < n; ++i) AMAX(acc[0], rk[i]);
  if (k < N) {
    const double *restrict Ek = d->E + (size_t)k * nx * nb, *restrict ek = d->e + (size_t)k * nx;
    const double *restrict xn = s->w + (size_t)(k + 1) * nb;
    double *restrict qk = s->req + (size_t)k * nx;
    UNROLL for (i = 0; i < nx; ++i) {
      double a = ek[i] - xn[i];
      UNROLL for (j = 0; j < n; ++j) a += Ek[i + j * nx] * wk[j];
      qk[i] = a;
      AMAX(acc[1], a);
    }
  }
  stage_rows(n, m, d->C + (size_t)k * nc * nb, wk, dr);
  for (i = s->kside[k]; i < s->kside[k + 1]; ++i) {
    s->r[i] = s->sg[i] * (dr[s->srow[i] - k * nr] - s->b[i]) - s->s[i];
    AMAX(acc[2], s->r[i]);
  }
}

/* residuals at (w, pi, s, z); returns 0, or OCPQP_NONFINITE */
static int residuals(ocpqp_solver *s, const ocpqp_data *d, ocpqp_info *info) {
  int N = s->d.N, k;
  double acc[3] = {0.0, 0.0, 0.0}, mu = pair_sum(s, 0.0, NULL);
  for (k = 0; k < N; ++k) stage_residuals(s, d, k, DNB(s), DNC(s), acc);
  stage_residuals(s, d, N, DNX(s), DNCN(s), acc);
  if (s->nside > 0) mu /= s->nside;
  info->res_stat = acc[0]; info->res_eq = acc[1]; info->res_ineq = acc[2]; info->res_comp = mu;
  if (!(acc[0] + acc[1] + acc[2] + mu < HUGE_VAL)) return OCPQP_NONFINITE;
  return 0;
}

/* Cholesky factor Lp (n x n, lower) of a symmetric positive semidefinite A (lower triangle read, lda):
 * a pivot <= eps * (1 + |A_jj|) is a direction without curvature and its column is set to zero, so
 * Lp Lp' stays PSD under rounding. Returns 0; OCPQP_CHOL_INDEFINITE if a pivot is negative beyond
 * rounding (A is indefinite: Lp is then not used); OCPQP_NONFINITE on a NaN. */
#define OCPQP_CHOL_INDEFINITE (-1)
KERNEL int chol_psd(int n, const double *restrict A, int lda, double *restrict Lp) {
  int i, j, l;
  UNROLL for (j = 0; j < n; ++j) {
    double dj = A[j + j * lda];
    UNROLL for (l = 0; l < j; ++l) dj -= Lp[j + l * n] * Lp[j + l * n];
    if (dj != dj) return OCPQP_NONFINITE;
    if (dj <= 1e-14 * (1.0 + fabs(A[j + j * lda]))) {
      if (dj < -1e-9 * (1.0 + fabs(A[j + j * lda]))) return OCPQP_CHOL_INDEFINITE;
      UNROLL for (i = j; i < n; ++i) Lp[i + j * n] = 0.0;
      continue;
    }
    {  /* 1/sqrt(d) as sqrt(d) / d: the division runs beside the square root, not after it */
      double r = sqrt(dj), id = 1.0 / dj;
      Lp[j + j * n] = r;
      dj = r * id;
    }
    UNROLL for (i = j + 1; i < n; ++i) {
      double a = A[i + j * lda];
      UNROLL for (l = 0; l < j; ++l) a -= Lp[i + l * n] * Lp[j + l * n];
      Lp[i + j * n] = a * dj;
    }
  }
  return 0;
}

/* P_k from the lower triangle of A (leading dimension lda): its factor (or its indefiniteness flag) and Pf_k
 * (both triangles); 0 or a status */
KERNEL int store_p(ocpqp_solver *s, int k, const double *restrict A, int lda) {
  int nx = DNX(s), i, j, st = chol_psd(nx, A, lda, s->P + (size_t)k * nx * nx);
  double *restrict Pf = s->Pf + (size_t)k * nx * nx;
  if (st > 0) return st;
  s->pind[k] = st == OCPQP_CHOL_INDEFINITE;
  UNROLL for (j = 0; j < nx; ++j)
    UNROLL for (i = j; i < nx; ++i) Pf[i + j * nx] = Pf[j + i * nx] = A[i + j * lda];
  return 0;
}

/* the barrier terms of stage k's rows (nrk of them, first row r0): sig = sum over the row's sides of z/s; 1/s
 * of each side into s->is; the largest z/s into s->sigmax */
KERNEL void stage_sigma(ocpqp_solver *s, int k, int nrk, int r0, double *restrict sig) {
  int i;
  UNROLL for (i = 0; i < nrk; ++i) sig[i] = 0.0;
  for (i = s->kside[k]; i < s->kside[k + 1]; ++i) {
    double is = 1.0 / s->s[i], q = s->z[i] * is;
    s->is[i] = is;
    sig[s->srow[i] - r0] += q;
    if (q > s->sigmax) s->sigmax = q;
  }
}

/* Riccati factorisation of the Newton matrix (square-root form: P_k = Lp_k Lp_k'); 0 or a status */
static int factor(ocpqp_solver *s, const ocpqp_data *d) {
  int N = s->d.N, nx = DNX(s), nu = DNU(s), nb = DNB(s), nc = DNC(s), ncN = DNCN(s), k, i, j, l;
  int nr = nb + nc;
  double *restrict G = s->G, *restrict F = s->F;
  s->sigmax = 0.0;
  /* terminal: P_N = H_N + diag(sig) + C_N' diag(sig) C_N (lower triangle into G, ld nb) */
  {
    const double *restrict HN = d->H + (size_t)N * nb * nb, *restrict CTN = s->CT + (size_t)N * nc * nb;
    double *restrict sr = s->sigrow + (size_t)N * nr;
    stage_sigma(s, N, nx + ncN, N * nr, sr);
    UNROLL for (l = 0; l < ncN; ++l) {
      double a0 = sqrt(sr[nx + l]);
      UNROLL for (i = 0; i < nx; ++i) F[i + l * nx] = CTN[i + l * nx] * a0;
    }
    UNROLL for (j = 0; j < nx; ++j)
      UNROLL for (i = j; i < nx; ++i) {
        double a = HN[i + j * nx] + (i == j ? sr[i] : 0.0);
        UNROLL for (l = 0; l < ncN; ++l) a += F[i + l * nx] * F[j + l * nx];
        G[i + j * nb] = a;
      }
    if (store_p(s, N, G, nb)) return OCPQP_NONFINITE;
  }
  for (k = N - 1; k >= 0; --k) {
    const double *restrict Hk = d->H + (size_t)k * nb * nb;
    const double *restrict L1 = s->P + (size_t)(k + 1) * nx * nx, *restrict P1 = s->Pf + (size_t)(k + 1) * nx * nx;
    const double *restrict ETk = s->ET + (size_t)k * nx * nb, *restrict CTk = s->CT + (size_t)k * nc * nb;
    double *restrict Lk = s->L + (size_t)k * nu * nu, *restrict Yk = s->Y + (size_t)k * nu * nx;
    double *restrict Ldk = s->Ld + (size_t)k * nu, *restrict sr = s->sigrow + (size_t)k * nr;
    /* F = [E_k' Lp_{k+1}, C_k' diag(sqrt(sig))] (nb x (nx + nc)); an indefinite P_{k+1} has no square root:
     * F = [E_k' P_{k+1}, C_k' diag(sqrt(sig))] then */
    const int ind = s->pind[k + 1];
    stage_sigma(s, k, nr, k * nr, sr);
    if (!ind) {
      UNROLL for (l = 0; l < nx; ++l)
        UNROLL for (i = 0; i < nb; ++i) {
          double a = 0.0;
          UNROLL for (j = l; j < nx; ++j) a += ETk[i + j * nb] * L1[j + l * nx];
          F[i + l * nb] = a;
        }
    } else {
      UNROLL for (l = 0; l < nx; ++l)
        UNROLL for (i = 0; i < nb; ++i) {
          double a = 0.0;
          UNROLL for (j = 0; j < nx; ++j) a += ETk[i + j * nb] * P1[j + l * nx];
          F[i + l * nb] = a;
        }
    }
    UNROLL for (l = 0; l < nc; ++l) {
      double a0 = sqrt(sr[nb + l]);
      UNROLL for (i = 0; i < nb; ++i) F[i + (nx + l) * nb] = CTk[i + l * nb] * a0;
    }
    /* G = H + diag(sig) + F F' (indefinite P_{k+1}: + C' diag(sig) C + (E' P) E), lower triangle */
    UNROLL for (j = 0; j < nb; ++j)
      UNROLL for (i = j; i < nb; ++i) {
        double a = Hk[i + j * nb] + (i == j ? sr[i] : 0.0);
        if (!ind) {
          UNROLL for (l = 0; l < nx + nc; ++l) a += F[i + l * nb] * F[j + l * nb];
        } else {
          UNROLL for (l = nx; l < nx + nc; ++l) a += F[i + l * nb] * F[j + l * nb];
          UNROLL for (l = 0; l < nx; ++l) a += F[i + l * nb] * ETk[j + l * nb];
        }
        G[i + j * nb] = a;
      }
    /* Cholesky of G_uu + reg I */
    UNROLL for (j = 0; j < nu; ++j) {
      double dj = G[(nx + j) + (nx + j) * nb] + s->set.reg_prim;
      UNROLL for (l = 0; l < j; ++l) dj -= Lk[j + l * nu] * Lk[j + l * nu];
      if (!(dj > 0.0) || !(dj < HUGE_VAL)) return OCPQP_FACTORIZATION;
      {
        double r = sqrt(dj), id = 1.0 / dj;
        Lk[j + j * nu] = r;
        dj = Ldk[j] = r * id;
      }
      UNROLL for (i = j + 1; i < nu; ++i) {
        double a = G[(nx + i) + (nx + j) * nb];
        UNROLL for (l = 0; l < j; ++l) a -= Lk[i + l * nu] * Lk[j + l * nu];
        Lk[i + j * nu] = a * dj;
      }
    }
    /* Y = L^{-1} G_ux (nu x nx) */
    UNROLL for (j = 0; j < nx; ++j)
      UNROLL for (i = 0; i < nu; ++i) {
        double a = G[(nx + i) + j * nb];
        UNROLL for (l = 0; l < i; ++l) a -= Lk[i + l * nu] * Yk[l + j * nu];
        Yk[i + j * nu] = a * Ldk[i];
      }
    if (k == 0) break;  /* x_0 is fixed: P_0 is not needed */
    /* P_k = G_xx - Y'Y (lower, in place in G), then its Cholesky factor */
    UNROLL for (j = 0; j < nx; ++j)
      UNROLL for (i = j; i < nx; ++i) {
        double a = G[i + j * nb];
        UNROLL for (l = 0; l < nu; ++l) a -= Yk[l + i * nu] * Yk[l + j * nu];
        G[i + j * nb] = a;
      }
    if (store_p(s, k, G, nb)) return OCPQP_NONFINITE;
  }
  return 0;
}

/* the right-hand side of stage k's rows (nrk, first row r0) from its sides: q_row = sum sg (rc + z r) / s
 * (r, rc NULL: zero) */
KERNEL void stage_q(const ocpqp_solver *s, int k, int nrk, int r0, const double *restrict r, const double *restrict rc,
                    double *restrict q) {
  int i;
  UNROLL for (i = 0; i < nrk; ++i) q[i] = 0.0;
  if (rc && r)
    for (i = s->kside[k]; i < s->kside[k + 1]; ++i) q[s->srow[i] - r0] += s->sg[i] * (rc[i] + s->z[i] * r[i]) * s->is[i];
  else if (rc)
    for (i = s->kside[k]; i < s->kside[k + 1]; ++i) q[s->srow[i] - r0] += s->sg[i] * rc[i] * s->is[i];
  else if (r)
    for (i = s->kside[k]; i < s->kside[k + 1]; ++i) q[s->srow[i] - r0] += s->sg[i] * s->z[i] * r[i] * s->is[i];
}

/* the steps of stage k's sides from the stage's step dw_k (n bound rows, m general rows):
 * ds = sg dd_row + r, dz = -(rc + z ds) / s (r, rc NULL: zero) */
KERNEL void stage_side_steps(const ocpqp_solver *s, const ocpqp_data *d, int k, int n, int m, const double *restrict dwk,
                             const double *restrict r, const double *restrict rc, double *restrict ds,
                             double *restrict dz) {
  int nb = DNB(s), nr = nb + DNC(s), i;
  double *restrict dd = s->ddrow + (size_t)k * nr;
  stage_rows(n, m, d->C + (size_t)k * DNC(s) * nb, dwk, dd);
  if (r && rc)
    for (i = s->kside[k]; i < s->kside[k + 1]; ++i) {
      ds[i] = s->sg[i] * dd[s->srow[i] - k * nr] + r[i];
      dz[i] = -(rc[i] + s->z[i] * ds[i]) * s->is[i];
    }
  else if (rc)
    for (i = s->kside[k]; i < s->kside[k + 1]; ++i) {
      ds[i] = s->sg[i] * dd[s->srow[i] - k * nr];
      dz[i] = -(rc[i] + s->z[i] * ds[i]) * s->is[i];
    }
  else
    for (i = s->kside[k]; i < s->kside[k + 1]; ++i) {
      ds[i] = s->sg[i] * dd[s->srow[i] - k * nr] + (r ? r[i] : 0.0);
      dz[i] = -s->z[i] * ds[i] * s->is[i];
    }
}

/* one Newton solve for the residuals (rstat, req, r, rc) with the current factorisation (any of them NULL:
 * zero): fills dw, dpi, ds, dz */
static void solve_rhs(ocpqp_solver *s, const ocpqp_data *d, const double *rstat, const double *req,
                      const double *r, const double *rc, double *dw, double *dpi, double *ds, double *dz) {
  int N = s->d.N, nx = DNX(s), nu = DNU(s), nb = DNB(s), nc = DNC(s), ncN = DNCN(s), nr = nb + nc, k, i, l;
  double *restrict q = s->qrow, *restrict tt = s->t, *restrict hh = s->h;
  /* backward: p_N = gt_N; h = gt_k + E'(P_{k+1} r_eq_k + p_{k+1}); ell = L^{-1} h_u; p_k = h_x - Y' ell, with the
   * stage's gt_k = rstat_k + D_k' q_k */
  {
    const double *restrict CTN = s->CT + (size_t)N * nc * nb, *restrict rN = rstat ? rstat + (size_t)N * nb : NULL;
    double *restrict pN = s->p + (size_t)N * nx;
    stage_q(s, N, nx + ncN, N * nr, r, rc, q);
    UNROLL for (i = 0; i < nx; ++i) {
      double a = rN ? rN[i] + q[i] : q[i];
      UNROLL for (l = 0; l < ncN; ++l) a += CTN[i + l * nx] * q[nx + l];
      pN[i] = a;
    }
  }
  for (k = N - 1; k >= 0; --k) {
    const double *restrict P1 = s->Pf + (size_t)(k + 1) * nx * nx, *restrict p1 = s->p + (size_t)(k + 1) * nx;
    const double *restrict Lk = s->L + (size_t)k * nu * nu, *restrict Yk = s->Y + (size_t)k * nu * nx;
    const double *restrict Ldk = s->Ld + (size_t)k * nu, *restrict ETk = s->ET + (size_t)k * nx * nb;
    const double *restrict CTk = s->CT + (size_t)k * nc * nb, *restrict rs = rstat ? rstat + (size_t)k * nb : NULL;
    const double *restrict rk = req ? req + (size_t)k * nx : NULL;
    double *restrict ek = s->ell + (size_t)k * nu, *restrict pk = s->p + (size_t)k * nx;
    stage_q(s, k, nr, k * nr, r, rc, q);
    UNROLL for (i = 0; i < nx; ++i) {
      double a = p1[i];
      if (rk) {
        UNROLL for (l = 0; l < nx; ++l) a += P1[i + l * nx] * rk[l];
      }
      tt[i] = a;
    }
    UNROLL for (i = 0; i < nb; ++i) {
      double a = rs ? rs[i] + q[i] : q[i];
      UNROLL for (l = 0; l < nc; ++l) a += CTk[i + l * nb] * q[nb + l];
      UNROLL for (l = 0; l < nx; ++l) a += ETk[i + l * nb] * tt[l];
      hh[i] = a;
    }
    UNROLL for (i = 0; i < nu; ++i) {
      double a = hh[nx + i];
      UNROLL for (l = 0; l < i; ++l) a -= Lk[i + l * nu] * ek[l];
      ek[i] = a * Ldk[i];
    }
    if (k == 0) break;
    UNROLL for (i = 0; i < nx; ++i) {
      double a = hh[i];
      UNROLL for (l = 0; l < nu; ++l) a -= Yk[l + i * nu] * ek[l];
      pk[i] = a;
    }
  }
  /* forward: dx_0 = 0; du = -L^{-T} (Y dx + ell); dx+ = E dw + r_eq; dpi = P+ dx+ + p+; then the stage's
   * side steps */
  for (i = 0; i < nx; ++i) dw[i] = 0.0;
  for (k = 0; k < N; ++k) {
    const double *restrict Lk = s->L + (size_t)k * nu * nu, *restrict Yk = s->Y + (size_t)k * nu * nx;
    const double *restrict ek = s->ell + (size_t)k * nu, *restrict Ldk = s->Ld + (size_t)k * nu;
    const double *restrict Ek = d->E + (size_t)k * nx * nb, *restrict rk = req ? req + (size_t)k * nx : NULL;
    const double *restrict P1 = s->Pf + (size_t)(k + 1) * nx * nx, *restrict p1 = s->p + (size_t)(k + 1) * nx;
    double *dwk = dw + (size_t)k * nb, *restrict dxn = dw + (size_t)(k + 1) * nb, *restrict dpk = dpi + (size_t)k * nx;
    UNROLL for (i = 0; i < nu; ++i) {
      double a = ek[i];
      UNROLL for (l = 0; l < nx; ++l) a += Yk[i + l * nu] * dwk[l];
      dwk[nx + i] = a;
    }
    UNROLL for (i = nu - 1; i >= 0; --i) {
      double a = dwk[nx + i];
      UNROLL for (l = i + 1; l < nu; ++l) a -= Lk[l + i * nu] * dwk[nx + l];
      dwk[nx + i] = a * Ldk[i];
    }
    UNROLL for (i = 0; i < nu; ++i) dwk[nx + i] = -dwk[nx + i];
    UNROLL for (i = 0; i < nx; ++i) {
      double a = rk ? rk[i] : 0.0;
      UNROLL for (l = 0; l < nb; ++l) a += Ek[i + l * nx] * dwk[l];
      dxn[i] = a;
    }
    UNROLL for (i = 0; i < nx; ++i) {
      double a = p1[i];
      UNROLL for (l = 0; l < nx; ++l) a += P1[i + l * nx] * dxn[l];
      dpk[i] = a;
    }
    stage_side_steps(s, d, k, nb, nc, dwk, r, rc, ds, dz);
  }
  stage_side_steps(s, d, N, nx, ncN, dw + (size_t)N * nb, r, rc, ds, dz);
}

/* iterative refinement of (dw, dpi, ds, dz): the stationarity residual of the Newton system (the only
 * block not satisfied exactly by construction; it grows with the barrier terms z/s) is solved for again
 * and the correction added, up to max_ref times while it exceeds tol */
static void refine(ocpqp_solver *s, const ocpqp_data *d, int max_ref, double tol) {
  int i, j, nw = s->nw, nx = DNX(s), npi = s->d.N * DNX(s);
  for (j = 0; j < max_ref; ++j) {
    double rn = 0.0;
    row_multipliers(s, s->dz, s->lamrow2);
    stationarity(s, d, s->dw, s->dpi, s->lamrow2, s->rstat, s->rho);
    for (i = nx; i < nw; ++i) AMAX(rn, s->rho[i]);
    if (!(rn > tol)) return;
    solve_rhs(s, d, s->rho, NULL, NULL, NULL, s->dw2, s->dpi2, s->ds2, s->dz2);
    for (i = nx; i < nw; ++i) s->dw[i] += s->dw2[i];
    for (i = 0; i < npi; ++i) s->dpi[i] += s->dpi2[i];
    for (i = 0; i < s->nside; ++i) {
      s->ds[i] += s->ds2[i];
      s->dz[i] += s->dz2[i];
    }
  }
}

/* largest alpha in (0, amax] keeping s + alpha ds >= 0 and z + alpha dz >= 0 */
static double max_step(const ocpqp_solver *s, double amax) {
  /* four lanes (each the smallest ratio of its sides), then their minimum; s + a ds < 0 is the test -s > a ds
   * (rounding keeps the sign of a sum), without the sign test of ds (s, z > 0) */
  const double *restrict sl = s->s, *restrict z = s->z, *restrict ds = s->ds, *restrict dz = s->dz;
  double a0 = amax, a1 = amax, a2 = amax, a3 = amax;
  int i, n = s->nside;
#define OCPQP_RATIO(a, j) do { \
    if (sl[j] + (a) * ds[j] < 0.0) (a) = -sl[j] / ds[j]; \
    if (z[j] + (a) * dz[j] < 0.0) (a) = -z[j] / dz[j]; \
  } while (0)
  for (i = 0; i + 3 < n; i += 4) {
    OCPQP_RATIO(a0, i);
    OCPQP_RATIO(a1, i + 1);
    OCPQP_RATIO(a2, i + 2);
    OCPQP_RATIO(a3, i + 3);
  }
  for (; i < n; ++i) OCPQP_RATIO(a0, i);
#undef OCPQP_RATIO
  a0 = a1 < a0 ? a1 : a0;
  a2 = a3 < a2 ? a3 : a2;
  return a2 < a0 ? a2 : a0;
}

/* Centrality correctors (Gondzio, Comput. Optim. Appl. 6, 1996; Colombo & Gondzio, Comput. Optim. Appl. 41,
 * 2008). Mehrotra's direction alone can stall on degenerate QPs: on the MPC's energy epigraph (two rows
 * e >= v a / eta and e >= eta v a of one stage, both active at a kink) the multiplier has to move from one row
 * to the other; the Newton step overshoots, the step length is cut to 0.5-0.8 by the other row's pair, and
 * the iterate oscillates between the rows with mu not decreasing (one pair s z hundreds of times mu, the
 * other far below it). A corrector asks for a longer step alpha_t = alpha + OCPQP_CC_DELTA: at that trial
 * point every pair outside [OCPQP_CC_BMIN, OCPQP_CC_BMAX] * sigma mu is pushed back to the interval (the
 * push down capped at OCPQP_CC_BMAX sigma mu); the correction solves the Newton system for that
 * complementarity right-hand side alone (one more right-hand side, same factorisation) and is kept if the
 * step length grows by at least OCPQP_CC_GAMMA * OCPQP_CC_DELTA. Up to OCPQP_CORRECTORS correctors, only
 * when Mehrotra's step is shorter than OCPQP_CC_TRIGGER and the residuals are below mu (-DOCPQP_CORRECTORS=0:
 * none). */
#ifndef OCPQP_CORRECTORS
#define OCPQP_CORRECTORS 2
#endif
#define OCPQP_CC_TRIGGER 0.9
#define OCPQP_CC_DELTA 0.3
#define OCPQP_CC_BMIN 0.1
#define OCPQP_CC_BMAX 10.0
#define OCPQP_CC_GAMMA 0.1

/* add (sign +1) or remove (-1) the correction (dw2, dpi2, ds2, dz2) to or from the step (dw, dpi, ds, dz) */
static void add_correction(ocpqp_solver *s, double sign) {
  int i, nw = s->nw, npi = s->d.N * DNX(s);
  for (i = DNX(s); i < nw; ++i) s->dw[i] += sign * s->dw2[i];
  for (i = 0; i < npi; ++i) s->dpi[i] += sign * s->dpi2[i];
  for (i = 0; i < s->nside; ++i) {
    s->ds[i] += sign * s->ds2[i];
    s->dz[i] += sign * s->dz2[i];
  }
}

/* centrality correctors of the step (dw, dpi, ds, dz) towards the target complementarity tmu (see above) */
static void correct_centrality(ocpqp_solver *s, const ocpqp_data *d, double tmu) {
  int kc, i;
  double ap = max_step(s, 1.0), lo = OCPQP_CC_BMIN * tmu, hi = OCPQP_CC_BMAX * tmu;
  for (kc = 0; kc < OCPQP_CORRECTORS && ap < OCPQP_CC_TRIGGER; ++kc) {
    double at = ap + OCPQP_CC_DELTA, an;
    if (at > 1.0) at = 1.0;
    for (i = 0; i < s->nside; ++i) {
      double v = (s->s[i] + at * s->ds[i]) * (s->z[i] + at * s->dz[i]), t = 0.0;
      if (v < lo) t = lo - v;
      else if (v > hi) t = v - hi < hi ? hi - v : -hi;
      s->rc[i] = -t;  /* the Newton rows read z ds + s dz = -rc */
    }
    solve_rhs(s, d, NULL, NULL, NULL, s->rc, s->dw2, s->dpi2, s->ds2, s->dz2);
    add_correction(s, 1.0);
    an = max_step(s, 1.0);
    if (an < ap + OCPQP_CC_GAMMA * OCPQP_CC_DELTA) {
      add_correction(s, -1.0);
      return;
    }
    ap = an;
  }
}

/* Wide neighbourhood of the central path (Wright, Primal-Dual Interior-Point Methods, SIAM 1997, ch. 5:
 * N_-inf(gamma)): alpha is shortened (x OCPQP_NBH_SHRINK, at most OCPQP_NBH_TRIES times) until every pair
 * (s_i + alpha ds_i)(z_i + alpha dz_i) is >= OCPQP_NBH_GAMMA times the mean of the new pairs (or, for a pair
 * already below that, does not fall below its current value); if no such alpha is found (Mehrotra's
 * second-order term can shrink a pair for every alpha > 0), the step is not shortened (a safeguard that
 * blocked every step would stall the iteration). Without it a pair can collapse onto its
 * corner (s and z both ~ 0 while the solution needs its multiplier): Newton's linearisation of s z is then
 * useless for it, the steps are cut short by it and the iterate zig-zags (the RTI QPs' epigraph rows). */
#ifndef OCPQP_WARM_MU
#define OCPQP_WARM_MU 1e-4
#endif
#ifndef OCPQP_NBH_GAMMA
#define OCPQP_NBH_GAMMA 0.01
#endif
#define OCPQP_NBH_SHRINK 0.8
#define OCPQP_NBH_TRIES 10

static double neighbourhood_step(const ocpqp_solver *s, double alpha0) {
  int tries, i;
  double alpha = alpha0;
  for (tries = 0; tries < OCPQP_NBH_TRIES; ++tries, alpha *= OCPQP_NBH_SHRINK) {
    double pmin, m = pair_sum(s, alpha, &pmin) * (OCPQP_NBH_GAMMA / s->nside);
    if (pmin >= m) return alpha;  /* the usual case: every pair inside, one pass */
    for (i = 0; i < s->nside; ++i) {
      double pn = (s->s[i] + alpha * s->ds[i]) * (s->z[i] + alpha * s->dz[i]), p0 = s->s[i] * s->z[i];
      if (pn < (m < p0 ? m : p0)) break;
    }
    if (i == s->nside) return alpha;
  }
  return alpha0;
}

/* ------------------------------------------------------------------------------------------ solve */
static double merit(const ocpqp_info *info, const ocpqp_settings *set) {
  double r[4] = {info->res_stat, info->res_eq, info->res_ineq, info->res_comp};
  double t[4] = {set->tol_stat, set->tol_eq, set->tol_ineq, set->tol_comp}, m = 0.0;
  int j;
  for (j = 0; j < 4; ++j) {
    double q = t[j] > 0.0 ? r[j] / t[j] : (r[j] > 0.0 ? HUGE_VAL : 0.0);
    if (!(q <= m)) m = q;  /* also a NaN */
  }
  return m;
}

/* The acceptable level (as IPOPT's acceptable_tol): an iterate whose every residual is within
 * OCPQP_ACCEPT_FACTOR times its tolerance is kept (the best such, by the largest residual/tolerance ratio); if the
 * solve then fails (iteration limit, a breakdown of the factorisation or non-finite iterates), that iterate is
 * returned with status OCPQP_ACCEPTABLE instead of the last one. On degenerate QPs (a stopped car on its gap floor:
 * the floor, v >= 0 and the path rows active together) the complementarity can stall a little above the
 * tolerance (3.7e-9 against 1e-9) and the iterates then diverge (residuals 1e89 after 30 iterations): the
 * acceptable iterate is the useful answer. Once one is kept, an iterate OCPQP_DIVERGE times worse ends the solve
 * (the iterations after it would be wasted). */
#ifndef OCPQP_ACCEPT_FACTOR
#define OCPQP_ACCEPT_FACTOR 100.0
#endif
#ifndef OCPQP_DIVERGE
#define OCPQP_DIVERGE 1e6
#endif

/* the cold or the warm start (see ocpqp_solve_warm); the guess (gw, gpi, glw, glc) is read before any output is
 * written */
static int solve(ocpqp_solver *s, const ocpqp_data *d, int warm, int max_iter, const double *gw, const double *gpi,
                 const double *glw, const double *glc, double *w, double *pi, double *lam_w, double *lam_c,
                 ocpqp_info *info_out) {
  int N = s->d.N, nx = DNX(s), nu = DNU(s), nb = DNB(s), nc = DNC(s), ncN = DNCN(s), nw = s->nw;
  int nr = nb + nc, k, i, it, st = OCPQP_OK;
  double z0, best = HUGE_VAL;  /* the best acceptable iterate's merit (none yet) */
  ocpqp_info binfo;
  size_t nh = (size_t)N * nb * nb + (size_t)nx * nx, ncm = (size_t)N * nc * nb + (size_t)ncN * nx;
  ocpqp_info info_local, *info = info_out ? info_out : &info_local;
  info->iterations = 0;
  info->res_stat = info->res_eq = info->res_ineq = info->res_comp = 0.0;
  (void)nu;
  if (!d || !w || !d->H || !d->g || !d->E || !d->e || !d->x0 || !d->lbw || !d->ubw
      || ((nc > 0 || ncN > 0) && (!d->C || !d->lc || !d->uc))) {
    info->status = OCPQP_BAD_DIMS;
    return info->status;
  }
  /* data checks */
  if (!all_finite(d->H, nh) || !all_finite(d->g, (size_t)nw) || !all_finite(d->E, (size_t)N * nx * nb)
      || !all_finite(d->e, (size_t)N * nx) || !all_finite(d->x0, (size_t)nx) || !no_nan(d->lbw, (size_t)nw)
      || !no_nan(d->ubw, (size_t)nw)
      || (nc + ncN > 0 && (!all_finite(d->C, ncm) || !no_nan(d->lc, (size_t)N * nc + ncN)
                           || !no_nan(d->uc, (size_t)N * nc + ncN)))) {
    info->status = OCPQP_NONFINITE;
    return info->status;
  }
  if (warm && ((gw && !all_finite(gw, (size_t)nw)) || (gpi && !all_finite(gpi, (size_t)N * nx))
               || (glw && !all_finite(glw, (size_t)nw)) || (glc && !all_finite(glc, (size_t)N * nc + ncN)))) {
    info->status = OCPQP_NONFINITE;  /* a non-finite guess */
    return info->status;
  }
  /* transposed copies of E and C (the kernels then run over contiguous columns) */
  for (k = 0; k <= N; ++k) {
    int n = k < N ? nb : nx, m = k < N ? nc : ncN, j;
    if (m > 0) {
      const double *Ck = d->C + (size_t)k * nc * nb;
      double *CTk = s->CT + (size_t)k * nc * nb;
      for (j = 0; j < n; ++j)
        for (i = 0; i < m; ++i) CTk[j + i * n] = Ck[i + j * m];
    }
    if (k < N) {
      const double *Ek = d->E + (size_t)k * nx * nb;
      double *ETk = s->ET + (size_t)k * nx * nb;
      for (j = 0; j < nb; ++j)
        for (i = 0; i < nx; ++i) ETk[j + i * nb] = Ek[i + j * nx];
    }
  }
  /* sides */
  s->nside = 0;
  for (k = 0; k <= N; ++k) {
    int n = k < N ? nb : nx, m = k < N ? nc : ncN;
    s->kside[k] = s->nside;
    for (i = 0; i < n + m; ++i) {
      double lo, up;
      if (i < n) {
        if (k == 0 && i < nx) continue;
        lo = d->lbw[(size_t)k * nb + i]; up = d->ubw[(size_t)k * nb + i];
      } else {
        lo = d->lc[(size_t)k * nc + (i - n)]; up = d->uc[(size_t)k * nc + (i - n)];
      }
      if (lo > up && fabs(lo) < OCPQP_INF && fabs(up) < OCPQP_INF) { info->status = OCPQP_INFEASIBLE; return info->status; }
      if (fabs(lo) < OCPQP_INF) { s->srow[s->nside] = k * nr + i; s->sg[s->nside] = 1.0; s->b[s->nside++] = lo; }
      if (fabs(up) < OCPQP_INF) { s->srow[s->nside] = k * nr + i; s->sg[s->nside] = -1.0; s->b[s->nside++] = up; }
    }
  }
  s->kside[N + 1] = s->nside;
  /* initial point: w = 0 with x_0 = x0, pi = 0, s = max(slack, 1), z = 2 z0 / s^(1/4) with z0 = sqrt(max(1,
   * |g|inf)) (duals of the cost gradient's scale: fewer short first steps than z = 1 when the gradient is
   * large; smaller on far bounds, so the first pairs s z are closer to each other: on the harvested RTI QPs
   * of the drive cycles 1.1 fewer iterations on the paper's cycle than z = z0, tuned there among z0 s^-p) */
  {
    double gmax = 1.0;
    for (i = 0; i < nw; ++i) AMAX(gmax, d->g[i]);
    z0 = sqrt(gmax);
  }
  if (warm && gw) memcpy(s->w, gw, (size_t)nw * sizeof(double));
  else memset(s->w, 0, (size_t)nw * sizeof(double));
  memcpy(s->w, d->x0, (size_t)nx * sizeof(double));
  if (warm && gpi) memcpy(s->pi, gpi, (size_t)N * nx * sizeof(double));
  else memset(s->pi, 0, (size_t)N * nx * sizeof(double));
  row_values(s, d, s->w, s->drow);
  if (!warm) {
    for (i = 0; i < s->nside; ++i) {
      double sl = s->sg[i] * (s->drow[s->srow[i]] - s->b[i]);
      s->s[i] = sl > 1.0 ? sl : 1.0;
      s->z[i] = 2.0 * z0 / sqrt(sqrt(s->s[i]));
    }
  } else {
    /* warm start: each side's slack at the guess w and its multiplier from the guess's row multiplier (the
     * side's part of lam_row = sum -sg z), then every pair lifted to s z >= OCPQP_WARM_MU (the larger of s, z
     * kept when it is >= sqrt(OCPQP_WARM_MU), the other raised; else both sqrt(OCPQP_WARM_MU)): a pair on its
     * corner (s, z ~ 0) would make the Newton steps useless for it (see neighbourhood_step) */
    const double mu0 = OCPQP_WARM_MU, r0 = sqrt(OCPQP_WARM_MU);
    for (i = 0; i < s->nside; ++i) {
      int row = s->srow[i], kr = row / nr, j = row - kr * nr, n = kr < N ? nb : nx;
      double lam = 0.0, sl = s->sg[i] * (s->drow[row] - s->b[i]), zi;
      if (j < n) { if (glw) lam = glw[(size_t)kr * nb + j]; }
      else if (glc) lam = glc[(size_t)kr * nc + (j - n)];
      zi = -s->sg[i] * lam;
      if (!(zi > 0.0)) zi = 0.0;  /* also a NaN guess */
      if (!(sl > 0.0)) sl = 0.0;
      if (!(sl * zi >= mu0)) {
        if (sl >= r0 && sl >= zi) zi = mu0 / sl;
        else if (zi >= r0) sl = mu0 / zi;
        else sl = zi = r0;
      }
      s->s[i] = sl;
      s->z[i] = zi;
    }
  }
  for (it = 0;; ++it) {
    double mu, alpha;
    st = residuals(s, d, info);
    if (st) break;
    if (info->res_stat <= s->set.tol_stat && info->res_eq <= s->set.tol_eq && info->res_ineq <= s->set.tol_ineq
        && info->res_comp <= s->set.tol_comp) {
      st = OCPQP_OK;
      break;
    }
    {
      /* the merit: the largest residual/tolerance ratio (a tolerance 0 never accepts) */
      double m = merit(info, &s->set);
      if (m <= OCPQP_ACCEPT_FACTOR && m < best) {
        best = m;
        binfo = *info;
        memcpy(s->bw, s->w, (size_t)nw * sizeof(double));
        memcpy(s->bpi, s->pi, (size_t)N * nx * sizeof(double));
        memcpy(s->blam, s->lamrow, (size_t)s->nrow * sizeof(double));
        memcpy(s->brs, s->rstat, (size_t)nx * sizeof(double));
      } else if (best < HUGE_VAL && !(m <= OCPQP_DIVERGE * best)) {
        st = OCPQP_MAX_ITER;  /* diverging from an acceptable iterate */
        break;
      }
    }
    if (it >= max_iter) { st = OCPQP_MAX_ITER; break; }
    st = factor(s, d);
    if (st) break;
    mu = info->res_comp;
    /* predictor */
    for (i = 0; i < s->nside; ++i) s->rc[i] = s->s[i] * s->z[i];
    solve_rhs(s, d, s->rstat, s->req, s->r, s->rc, s->dw, s->dpi, s->ds, s->dz);
    if (s->nside > 0) {
      double mu_aff = 0.0, sigma;
      alpha = max_step(s, 1.0);
      mu_aff = pair_sum(s, alpha, NULL) / s->nside;
      sigma = mu > 0.0 ? mu_aff / mu : 0.0;
      sigma = sigma * sigma * sigma;
      if (sigma > 1.0) sigma = 1.0;
      /* corrector */
      for (i = 0; i < s->nside; ++i) s->rc[i] = s->s[i] * s->z[i] + s->ds[i] * s->dz[i] - sigma * mu;
      solve_rhs(s, d, s->rstat, s->req, s->r, s->rc, s->dw, s->dpi, s->ds, s->dz);
      /* correctors only in the end game (residuals below mu): earlier they lengthen steps that the
       * infeasibility, not the centrality, limits, and cost iterations (the paper's drive cycle) */
      if (info->res_stat <= mu && info->res_eq <= mu && info->res_ineq <= mu) correct_centrality(s, d, sigma * mu);
      {
        /* refine only where the Newton step's error would matter: against the current residuals */
        double rmax = info->res_stat;
        if (info->res_eq > rmax) rmax = info->res_eq;
        if (info->res_ineq > rmax) rmax = info->res_ineq;
        if (mu > rmax) rmax = mu;
        rmax *= 1e-3;
        if (rmax < 0.1 * s->set.tol_stat) rmax = 0.1 * s->set.tol_stat;
        /* the reduced solve's error grows like eps * max(z/s) * |dw|: skip the check while that is far below */
        {
          double dwmax = 0.0;
          for (i = nx; i < nw; ++i) AMAX(dwmax, s->dw[i]);
          if (1e-13 * s->sigmax * (1.0 + dwmax) > rmax) refine(s, d, 4, rmax);
        }
      }
      {
        /* fraction to the boundary: 0.995; a warm start's end game 1 - mu (as IPOPT's tau = max(tau_min, 1 - mu)):
         * with 0.995 every residual falls by exactly 1 - 0.995 per step (an iterate whose Newton step ends on
         * the boundary is held 0.5 % short of it), so the MPC's warm-started QPs needed 4-5 iterations to go
         * from the lifted mu 1e-4 to 1e-9; with 1 - mu, 2-3. Not for the cold start: from its far point the
         * longer steps cost iterations (288 instead of 203 in the canonical MPC's cold start). */
        double tau = warm ? 1.0 - mu : 0.995;
        if (tau < 0.995) tau = 0.995;
        alpha = tau * max_step(s, 1.0 / tau);
      }
      if (alpha > 1.0) alpha = 1.0;
      if (OCPQP_NBH_GAMMA > 0.0) alpha = neighbourhood_step(s, alpha);
    } else {
      alpha = 1.0;
    }
    for (i = nx; i < nw; ++i) s->w[i] += alpha * s->dw[i];
    for (i = 0; i < N * nx; ++i) s->pi[i] += alpha * s->dpi[i];
    for (i = 0; i < s->nside; ++i) {
      s->s[i] += alpha * s->ds[i];
      s->z[i] += alpha * s->dz[i];
    }
    info->iterations = it + 1;
  }
  if (st != OCPQP_OK && best < HUGE_VAL) {  /* failed after an acceptable iterate: that one (see OCPQP_ACCEPT_FACTOR) */
    memcpy(s->w, s->bw, (size_t)nw * sizeof(double));
    memcpy(s->pi, s->bpi, (size_t)N * nx * sizeof(double));
    memcpy(s->lamrow, s->blam, (size_t)s->nrow * sizeof(double));
    memcpy(s->rstat, s->brs, (size_t)nx * sizeof(double));
    info->res_stat = binfo.res_stat; info->res_eq = binfo.res_eq;
    info->res_ineq = binfo.res_ineq; info->res_comp = binfo.res_comp;
    st = OCPQP_ACCEPTABLE;
  }
  /* outputs (the last iterate, or the acceptable one; lam of x_0 closes the stationarity of x_0) */
  memcpy(w, s->w, (size_t)nw * sizeof(double));
  if (pi) memcpy(pi, s->pi, (size_t)N * nx * sizeof(double));
  if (lam_w || lam_c) {
    for (k = 0; k <= N; ++k) {
      int n = k < N ? nb : nx, m = k < N ? nc : ncN;
      const double *lr = s->lamrow + (size_t)k * nr;
      if (lam_w)
        for (i = 0; i < n; ++i) lam_w[(size_t)k * nb + i] = (k == 0 && i < nx) ? -s->rstat[i] : lr[i];
      if (lam_c)
        for (i = 0; i < m; ++i) lam_c[(size_t)k * nc + i] = lr[n + i];
    }
  }
  info->status = st;
  return st;
}

int ocpqp_solve(ocpqp_solver *s, const ocpqp_data *d, double *w, double *pi, double *lam_w, double *lam_c,
                ocpqp_info *info) {
  return solve(s, d, 0, s->set.max_iter, NULL, NULL, NULL, NULL, w, pi, lam_w, lam_c, info);
}

/* The warm start gets at most OCPQP_WARM_MAX_ITER iterations (the MPC's warm-started QPs take 3-8); if it fails
 * (iteration limit, or a control block not positive definite: the barrier terms of a poor guess are too small to
 * convexify an indefinite H_k), the QP is solved again from the cold start, and the iterations add up. */
#ifndef OCPQP_WARM_MAX_ITER
#define OCPQP_WARM_MAX_ITER 15
#endif

int ocpqp_solve_warm(ocpqp_solver *s, const ocpqp_data *d, const double *w0, const double *pi0, const double *lam_w0,
                     const double *lam_c0, double *w, double *pi, double *lam_w, double *lam_c, ocpqp_info *info) {
  ocpqp_info info_local, *inf = info ? info : &info_local;
  int st, it, cap = s->set.max_iter < OCPQP_WARM_MAX_ITER ? s->set.max_iter : OCPQP_WARM_MAX_ITER;
  st = solve(s, d, 1, cap, w0, pi0, lam_w0, lam_c0, w, pi, lam_w, lam_c, inf);
  if (st != OCPQP_MAX_ITER && st != OCPQP_FACTORIZATION) return st;
  it = inf->iterations;
  st = solve(s, d, 0, s->set.max_iter, NULL, NULL, NULL, NULL, w, pi, lam_w, lam_c, inf);
  inf->iterations += it;
  return st;
}
