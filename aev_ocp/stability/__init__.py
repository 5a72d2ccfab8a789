"""String stability of car-following laws and of the MPC platoon.

Linear analysis of any :class:`~aev_ocp.models.carfollowing.CarFollowingLaw` at an equilibrium
(:mod:`.linear`: exact CasADi partials, head-to-tail criterion, transfer function, sup|G|, unstable
band, platoon stability) and measured attenuation in long perturbed platoons (:mod:`.measure`) are
exported here (imported on first use); the modes of a ring road (:mod:`.ring`) and of a mixed ring
(:mod:`.mixed`), the runs that write files and maps (:mod:`.run`), plots (:mod:`.plots`), the ``aev-ocp
stability`` command (:mod:`.cli`, with ``--ring``) and the section of ``aev-ocp reproduce`` (:mod:`.section`) are
imported from their modules (docs/guide/layers.md).

Python API (model units throughout)::

    from aev_ocp.stability import analyse, measure
    from aev_ocp.stability.run import stability_map, study_metrics, run_stability
    lin = analyse(Proposed(), 1.7)            # LinearStability: criterion, max_gain, unstable_band, ...
    att = measure(Proposed(), 1.7, 1e-3)      # Attenuation of a dip of depth 1e-3 in 50 followers
    m = stability_map(Proposed(), 1.7, "alpha", np.linspace(0, 4, 21), "beta", np.linspace(0, 6, 21))
"""

from ..lazy import lazy_exports

#: name -> module that defines it (imported on first use: aev_ocp.lazy)
_EXPORTS = {
    "LinearizedLaw": "linear",
    "LinearStability": "linear",
    "analyse": "linear",
    "analyse_speeds": "linear",
    "equilibrium_gap_of": "linear",
    "head_to_tail_criterion": "linear",
    "max_gain": "linear",
    "partials_function": "linear",
    "peak_gain": "linear",
    "transfer": "linear",
    "Attenuation": "measure",
    "attenuation_of": "measure",
    "fig5_amplitude": "measure",
    "linear_prediction": "measure",
    "measure": "measure",
    "measure_mpc": "measure",
    "sweep_amplitudes": "measure",
    "PerturbedLeader": "perturbation",
}

__all__ = [
    "Attenuation",
    "LinearStability",
    "LinearizedLaw",
    "PerturbedLeader",
    "analyse",
    "analyse_speeds",
    "attenuation_of",
    "equilibrium_gap_of",
    "fig5_amplitude",
    "head_to_tail_criterion",
    "linear_prediction",
    "max_gain",
    "measure",
    "measure_mpc",
    "partials_function",
    "peak_gain",
    "sweep_amplitudes",
    "transfer",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
