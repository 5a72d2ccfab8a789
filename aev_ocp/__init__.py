"""aev_ocp: energy-aware control of autonomous electric vehicles, built on CasADi.

Layers: ``params`` (parameter sets with units and sources), ``models`` (symbolic physical models),
``simulate`` and ``metrics`` (closed-form laws in closed loop), ``ocp`` and ``mpc`` (optimal control),
``scenarios`` (TOML scenario files), ``report``/``cli`` (figures, tables, command line).
"""

__version__ = "0.1.0"
