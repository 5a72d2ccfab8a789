/* mpc_bench_main.c — replays recorded MPC inputs through aev_mpc_step and times every call
 * (clock_gettime, CLOCK_MONOTONIC). Hand-written template of aev_ocp (aev_ocp/c/mpc_bench_main.c).
 *
 * Usage: mpc_bench INPUT [OUTPUT]
 *   INPUT:  K lines of NZ + 2N numbers in SI: x_meas (h [m], v [m/s], V1 [V], V2 [V], S [-]), then the forecast
 *           (v_l_mean[N], v_l_hat[N] [m/s]), one line per step of AEV_MPC_DT_S seconds (aev-ocp mpc-export
 *           writes mpc_input.txt, a recorded one)
 *   OUTPUT: K lines "status u[0] ... u[NU-1] wall_seconds cpu_seconds" (optional; u in SI, u[0] [m/s^2])
 * Prints the median, p95 and max wall time per step [ms] after the first (cold) step (CPU time, which
 * excludes preemption on a shared machine, goes to OUTPUT).
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "mpc_config.h"
#include "mpc_step.h"

static int cmp(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

int main(int argc, char **argv) {
  FILE *in, *out = NULL;
  int k = 0, i, n, status, cap = 1024;
  double xm[AEV_MPC_NZ], fc[2 * AEV_MPC_N], u[AEV_MPC_NU];
  double *t = (double *)malloc(sizeof(double) * cap), cpu;
  aev_mpc_workspace *ws;
  struct timespec t0, t1, c0, c1;
  if (argc < 2) { fprintf(stderr, "usage: %s INPUT [OUTPUT]\n", argv[0]); return 2; }
  in = fopen(argv[1], "r");
  if (!in) { perror(argv[1]); return 2; }
  if (argc > 2 && !(out = fopen(argv[2], "w"))) { perror(argv[2]); return 2; }
  ws = aev_mpc_create();
  if (!ws || !t) { fprintf(stderr, "out of memory\n"); return 1; }
  for (;;) {
    for (i = 0; i < AEV_MPC_NZ; ++i) if (fscanf(in, "%lf", &xm[i]) != 1) goto done;
    for (i = 0; i < 2 * AEV_MPC_N; ++i) if (fscanf(in, "%lf", &fc[i]) != 1) { fprintf(stderr, "short line %d\n", k + 1); return 2; }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c0);
    clock_gettime(CLOCK_MONOTONIC, &t0);
    aev_mpc_step(ws, xm, fc, u, &status);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c1);
    cpu = (double)(c1.tv_sec - c0.tv_sec) + 1e-9 * (double)(c1.tv_nsec - c0.tv_nsec);
    if (k == cap) { cap *= 2; t = (double *)realloc(t, sizeof(double) * cap); if (!t) return 1; }
    t[k] = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    if (out) {
      fprintf(out, "%d", status);
      for (i = 0; i < AEV_MPC_NU; ++i) fprintf(out, " %.17g", u[i]);
      fprintf(out, " %.9g %.9g\n", t[k], cpu);
    }
    ++k;
  }
done:
  fclose(in);
  if (out) fclose(out);
  aev_mpc_free(ws);
  if (k < 2) { fprintf(stderr, "need at least 2 steps, got %d\n", k); return 2; }
  n = k - 1;
  qsort(t + 1, (size_t)n, sizeof(double), cmp);
  printf("steps %d first_ms %.4f median_ms %.4f p95_ms %.4f max_ms %.4f\n", k, 1e3 * t[0],
         1e3 * (n % 2 ? t[1 + n / 2] : 0.5 * (t[n / 2] + t[1 + n / 2])), 1e3 * t[1 + (int)(0.95 * (n - 1))],
         1e3 * t[n]);
  free(t);
  return 0;
}
