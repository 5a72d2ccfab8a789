"""Physical models: car-following laws, leader profiles, vehicle, 2-RC cell, powertrain/current map.

Models return CasADi expressions or Functions and know nothing of solvers, files or plots.
"""

from . import battery, carfollowing, energy, leader, powertrain, vehicle
from .carfollowing import (
    IDM,
    IDM_TREIBER,
    LAW_REGISTRY,
    OVFL,
    OVM,
    V_INF,
    CarFollowingLaw,
    IDMModelUnits,
    OVLaw,
    Proposed,
    energy_term,
    equilibrium_gap,
    make_law,
    optimal_velocity,
    register_law,
)
from .leader import BrakingLeader, ConstantSpeed, LeaderProfile, PaperLeader, SpeedTrace, drive_cycle

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
