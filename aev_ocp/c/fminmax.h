/* ---------------- aev_ocp: fmax and fmin inline ----------------
 * Put before CasADi-generated code (aev_ocp.ring.simulate): its casadi_fmax/casadi_fmin call the C library's fmax/fmin,
 * which GCC never inlines without -ffinite-math-only (a call in the middle of every right-hand side: every vector
 * register saved and restored around it). These return what x86-64 glibc's fmax/fmin return (maxsd/minsd after an
 * unordered check): the larger (smaller) of x and y, y when they compare equal (so of +0 and -0, y), the other one
 * when one is NaN: on x86-64 glibc (checked over ±0, ±inf, NaN) the same number as the library's in every case;
 * elsewhere at most the sign of a zero max/min of +0 and -0 could differ from that C library's choice. */
#ifndef AEV_FMINMAX_H
#define AEV_FMINMAX_H
#include <math.h>

static inline double aev_fmax(double x, double y) { return (x > y || y != y) ? x : y; }
static inline double aev_fmin(double x, double y) { return (x < y || y != y) ? x : y; }
#define fmax(x, y) aev_fmax(x, y)
#define fmin(x, y) aev_fmin(x, y)
#endif
