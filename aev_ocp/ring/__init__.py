"""Mixed traffic on a ring road (issue 22): ring roads with human drivers and AEVs, the compiled ring
simulator, the ring closed loop for sampled controllers, linear ring stability and the ring experiments
(Sugiyama et al. 2008, Stern et al. 2018). ``aev-ocp ring`` lives in :mod:`aev_ocp.ring.cli`."""
