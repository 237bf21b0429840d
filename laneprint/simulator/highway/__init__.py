"""A study generator on highway-env (`laneprint simulate --engine highway`).

The drivers are highway-env's `IDMVehicle`s: IDM car following and MOBIL lane
changes, with each driver's constants from its style (`styles.py`) and a person's
inconsistency, reaction time, aborted and missed presses on top (`driver.py`), in
traffic written by highway-env too (`traffic.py`, `world.py`): a world not written
by us to judge the analysis on.

Public API: `HighwaySettings`, `simulate_highway_study(settings, seed) -> HighwayStudy`,
`STYLE_PARAMS`, `make_highway_drivers`,
`true_parameter_ari`. highway-env itself (the `highway` extra, `pip install -e
'.[highway]'`) is only imported when recordings are simulated.
"""

from laneprint.simulator.highway.settings import HighwaySettings
from laneprint.simulator.highway.styles import STYLE_PARAMS, HighwayDriver, make_highway_drivers, true_parameter_ari
from laneprint.simulator.highway.study import HighwayStudy, simulate_highway_study


__all__ = [
    "STYLE_PARAMS",
    "HighwayDriver",
    "HighwaySettings",
    "HighwayStudy",
    "make_highway_drivers",
    "simulate_highway_study",
    "true_parameter_ari",
]
