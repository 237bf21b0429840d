"""An independent study generator on Eclipse SUMO (`laneprint simulate --engine sumo`).

The drivers decide by SUMO's own models (Krauss or IDM car following, LC2013 or SL2015 lane
changes), not by laneprint's: a test of whether the analysis generalises. See
`laneprint/simulator/SUMO.md`.

Public API: `SumoSettings`, `simulate_sumo_study(settings, seed) -> SumoStudy`,
`STYLE_PARAMS`. SUMO itself is only needed
when a study is simulated (`pip install -e '.[sumo]'`).
"""

from laneprint.simulator.sumo.settings import SumoSettings
from laneprint.simulator.sumo.styles import STYLE_PARAMS, SumoDriver, make_sumo_drivers
from laneprint.simulator.sumo.study import SumoStudy, simulate_sumo_study


__all__ = ["STYLE_PARAMS", "SumoDriver", "SumoSettings", "SumoStudy", "make_sumo_drivers", "simulate_sumo_study"]
