"""Physical models: car-following laws, leader profiles, vehicle, 2-RC cell, powertrain/current map.

Models return CasADi expressions or Functions and know nothing of solvers, files or plots.
"""

from ..lazy import lazy_exports

#: name -> module that defines it (imported on first use: aev_ocp.lazy)
_EXPORTS = {
    "battery": "battery",
    "carfollowing": "carfollowing",
    "energy": "energy",
    "leader": "leader",
    "powertrain": "powertrain",
    "vehicle": "vehicle",
    "IDM": "carfollowing",
    "IDM_TREIBER": "carfollowing",
    "LAW_REGISTRY": "carfollowing",
    "OVFL": "carfollowing",
    "OVM": "carfollowing",
    "V_INF": "carfollowing",
    "CarFollowingLaw": "carfollowing",
    "IDMModelUnits": "carfollowing",
    "OVLaw": "carfollowing",
    "Proposed": "carfollowing",
    "energy_term": "carfollowing",
    "equilibrium_gap": "carfollowing",
    "make_law": "carfollowing",
    "optimal_velocity": "carfollowing",
    "register_law": "carfollowing",
    "BrakingLeader": "leader",
    "ConstantSpeed": "leader",
    "LeaderProfile": "leader",
    "PaperLeader": "leader",
    "SpeedTrace": "leader",
    "drive_cycle": "leader",
}

__all__ = [
    "battery",
    "carfollowing",
    "energy",
    "leader",
    "powertrain",
    "vehicle",
    "IDM",
    "IDM_TREIBER",
    "IDMModelUnits",
    "LAW_REGISTRY",
    "OVLaw",
    "OVFL",
    "OVM",
    "V_INF",
    "CarFollowingLaw",
    "Proposed",
    "energy_term",
    "equilibrium_gap",
    "make_law",
    "optimal_velocity",
    "register_law",
    "BrakingLeader",
    "ConstantSpeed",
    "LeaderProfile",
    "PaperLeader",
    "SpeedTrace",
    "drive_cycle",
]

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
