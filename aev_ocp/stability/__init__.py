"""String stability of car-following laws and of the MPC platoon (issue 14).

Linear analysis of any :class:`~aev_ocp.models.carfollowing.CarFollowingLaw` at an equilibrium
(:mod:`.linear`: exact CasADi partials, head-to-tail criterion, transfer function, sup|G|, unstable
band, platoon stability), measured attenuation in long perturbed platoons (:mod:`.measure`), plots,
the ``aev-ocp stability`` command (:mod:`.cli`) and a section of ``aev-ocp reproduce`` (:mod:`.report`).

Python API (model units throughout)::

    from aev_ocp.stability import analyse, measure, stability_map, study_metrics, run_stability
    lin = analyse(Proposed(), 1.7)            # LinearStability: criterion, max_gain, unstable_band, ...
    att = measure(Proposed(), 1.7, 1e-3)      # Attenuation of a dip of depth 1e-3 in 50 followers
    m = stability_map(Proposed(), 1.7, "alpha", np.linspace(0, 4, 21), "beta", np.linspace(0, 6, 21))
"""

from .api import SIGN_CONVENTION, default_amplitudes, run_stability, stability_map, study_metrics
from .cli import cli_stability
from .linear import (LinearizedLaw, LinearStability, analyse, analyse_speeds, equilibrium_gap_of,
                     head_to_tail_criterion, max_gain, partials_function, peak_gain, transfer)
from .measure import (Attenuation, attenuation_of, fig5_amplitude, linear_prediction, measure, measure_mpc,
                      sweep_amplitudes)
from .perturbation import PerturbedLeader
from .report import REPRODUCE_SECTIONS, string_stability_section

__all__ = ["SIGN_CONVENTION", "Attenuation", "LinearStability", "LinearizedLaw", "PerturbedLeader", "REPRODUCE_SECTIONS", "analyse",
           "analyse_speeds", "attenuation_of", "cli_stability", "default_amplitudes", "equilibrium_gap_of",
           "fig5_amplitude", "head_to_tail_criterion", "linear_prediction", "max_gain", "measure", "measure_mpc",
           "partials_function", "peak_gain", "run_stability", "stability_map", "string_stability_section", "study_metrics",
           "sweep_amplitudes", "transfer"]
