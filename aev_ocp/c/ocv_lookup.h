/* ---------------- aev_ocp: the cell's OCV(S) by table lookup ----------------
 * Included by ring.c (aev_ocp.compiled.driver_source inlines it). Needs from the generated prologue the table of
 * aev_ocp.models.battery.ocv_segments: AEV_OCV_NSEG pieces, AEV_OCV_GRID (the AEV_OCV_NSEG + 1 breakpoints, strictly
 * increasing) and AEV_OCV_COEF (per piece s0, a, b, c, d). The value is that of ocv_piecewise to the bit: the same
 * piece (the largest k in 1..NSEG-1 with S >= grid[k], else 0; NaN: 0) and the same operations on the same numbers,
 * a + u (b + u (c + u d)) with u = S - s0. ocv_piecewise finds the piece with NSEG - 1 comparisons and sums the
 * pieces' differences masked by them; here a guess from the grid's mean spacing, walked to the right piece (exact on
 * any increasing grid, one or two comparisons on a near-uniform one such as the shipped A123 table's). */
#ifndef AEV_OCV_LOOKUP_H
#define AEV_OCV_LOOKUP_H

static const double AEV_OCV_GRID_TAB[AEV_OCV_NSEG + 1] = AEV_OCV_GRID;
static const double AEV_OCV_COEF_TAB[AEV_OCV_NSEG][5] = AEV_OCV_COEF;

static inline double aev_ocv(double S) {
  const double* g = AEV_OCV_GRID_TAB;
  double t = (S - g[0]) * ((double)AEV_OCV_NSEG / (g[AEV_OCV_NSEG] - g[0]));
  int k = t > 0 ? (t < AEV_OCV_NSEG - 1 ? (int)t : AEV_OCV_NSEG - 1) : 0; /* NaN: 0 */
  while (k > 0 && !(S >= g[k])) k--;
  while (k < AEV_OCV_NSEG - 1 && S >= g[k + 1]) k++;
  const double* c = AEV_OCV_COEF_TAB[k];
  double u = S - c[0];
  return c[1] + u * (c[2] + u * (c[3] + u * c[4]));
}
#endif
