"""A study generator on highway-env (`laneprint simulate --engine highway`).

The drivers are highway-env's `IDMVehicle`s: IDM car following and MOBIL lane
changes, with each driver's constants from its style (`styles.py`) and a person's
inconsistency, reaction time, aborted and missed presses on top (`driver.py`), in
traffic written by highway-env too (`traffic.py`, `world.py`): a world not written
by us to judge the analysis on.

Public API: `HighwaySettings`, `simulate_highway_study(settings, seed) -> HighwayStudy`,
`write_highway_study(study, out, fmt)`, `STYLE_PARAMS`, `make_highway_drivers`,
`true_parameter_ari`. highway-env itself (the `highway` extra, `pip install -e
'.[highway]'`) is only imported when recordings are simulated.
"""

from laneprint.simulator.highway.settings import HighwaySettings
from laneprint.simulator.highway.styles import STYLE_PARAMS, HighwayDriver, make_highway_drivers, true_parameter_ari
from laneprint.simulator.highway.study import HighwayStudy, simulate_highway_study


def write_highway_study(*args, **kwargs):  # noqa: ANN002, ANN003 - thin lazy wrapper
    """See `laneprint.simulator.highway.output.write_highway_study`."""
    from laneprint.simulator.highway.output import write_highway_study as _write

    return _write(*args, **kwargs)


__all__ = ["STYLE_PARAMS", "HighwayDriver", "HighwaySettings", "HighwayStudy", "make_highway_drivers",
           "simulate_highway_study", "true_parameter_ari", "write_highway_study"]
