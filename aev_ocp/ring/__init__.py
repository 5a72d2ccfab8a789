"""Mixed traffic on a ring road: ring roads with human drivers and AEVs, the compiled ring
simulator, the ring closed loop for sampled controllers and the ring experiments (Sugiyama et al. 2008, Stern et
al. 2018). ``aev-ocp ring`` lives in :mod:`aev_ocp.ring.cli`; the ring's linear stability (its modes, and the
growth measured on this simulator) in :mod:`aev_ocp.stability.ring`, the ring's report section in
:mod:`aev_ocp.ring_section`. Nothing here imports :mod:`aev_ocp.stability` (docs/guide/layers.md)."""
