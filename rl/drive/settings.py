"""What `laneprint drive` does: the traffic it drives in and the assistant's rule beside the agent.

Every field is an option of `laneprint drive` and a key of the `[drive]` table of `--config`.
The settings are checked once, when they are made (`DriveSettings.__post_init__`: the values and their
combinations, a `SettingError` naming the settings); what needs the workspace (the run, the family of its
drivers' traffic) is checked when the drive is planned (`rl.drive.store.plan_drive`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from laneprint.errors import SettingError
from rl.drive.heldback import DWELL_PERCENTILE

#: The simulators `laneprint drive` drives in.
ENGINES = ("sumo",)


@dataclass(frozen=True)
class DriveSettings:
    """The drive's traffic and the assistant's held-back rule."""

    engine: str = "sumo"
    """Simulator: sumo (Eclipse SUMO, from the sumo extra of the install)."""
    minutes: float = 10.0
    """Minutes of driving per section."""
    seed: int = 0
    """Seed of the traffic and of SUMO."""
    lanes: int = 2
    """Lanes of the highway: 2 or 3; in a middle lane the agent is asked about each side and takes the one
    with the larger advantage Q(change) - Q(keep)."""
    family: Optional[str] = None
    """SUMO traffic and style vTypes of a study family: ttc or acceptance (as `laneprint simulate --family`).
    Default: that of the study the agent learnt from when its drivers drove a laneprint SUMO study, else ttc."""
    driver_id: Optional[str] = None
    """driver_id of the drive's logs (default agent-RUN_ID)."""
    analyze: bool = False
    """Analyse the workspace's study plus the drive (in a scratch workspace) and report the agent's style."""
    sumo_model: bool = True
    """Also drive the same ego with SUMO's own lane-change model of its style in the same traffic and seeds,
    as the comparator."""
    held_back: bool = True
    """The assistant's held-back rule: after following a leader slower than the ego's desired speed for the
    target's patience, change when a neighbouring lane is faster and holds a gap the target's acceptance
    lines take (`rl.drive.heldback`). Off: the pure agent."""
    dwell: bool = True
    """With the held-back rule: no change sooner after a lane change than the target's drivers pressed."""
    dwell_percentile: float = DWELL_PERCENTILE
    """The dwell's percentile of the drivers' times from a lane change to their next press (5: their floor;
    25: closer to drivers who stay long in the left lane)."""
    dwell_draw: bool = False
    """Draw each dwell from the target's drivers' own times from a change to their next press (seeded by
    the seed) instead of one percentile of them."""
    dwell_calibrated: Optional[bool] = None
    """Draw each dwell from the run's closed-loop calibration in this traffic (drives with the floor dwell
    give the agent's own stays; the dwell makes them like its drivers'). Default: on in the drivers' own
    traffic unless dwell_draw or no dwell; off elsewhere."""
    lag_draw: bool = False
    """With the held-back rule: at each lane change draw, per side, a follower time headway from the target's
    drivers' presses to that side; the agent's own change there needs at least that."""
    lag_calibrated: Optional[bool] = None
    """Draw that headway from the run's closed-loop calibration in this traffic. Default: on in its drivers'
    own traffic unless lag_draw; elsewhere the floors alone."""
    pace: bool = True
    """With the held-back rule: the agent's own change needs the advantage at which, replayed along its
    drivers' recordings, it wants a change no more often than they pressed (`rl.drive.pace`). Off: any
    advantage of at least 0."""
    pace_by: str = "pooled"
    """How the pace is read: 'pooled', one threshold for either side against all the drivers' presses;
    'side', one per side against their presses to that side."""
    undo_check: bool = True
    """With the held-back rule and no leader within range: a change to the left is requested only if, put in
    that lane as the traffic is, the agent would not want back at once."""

    def __post_init__(self) -> None:
        from laneprint.simulator.sumo.settings import FAMILIES, LANES
        from rl.drive.pace import PACE_BY

        if self.engine not in ENGINES:
            raise SettingError(f"unknown {{0}} {self.engine!r}; choose one of {', '.join(ENGINES)}", "engine")
        if self.family is not None and self.family not in FAMILIES:
            raise SettingError(f"unknown {{0}} {self.family!r}; choose one of {', '.join(FAMILIES)}", "family")
        if self.pace_by not in PACE_BY:
            raise SettingError(f"unknown {{0}} {self.pace_by!r}; choose one of {', '.join(PACE_BY)}", "pace_by")
        if self.dwell_draw and self.dwell_calibrated:
            raise SettingError("{0} and {1}: choose one", "dwell_draw", "dwell_calibrated")
        if (self.dwell_draw or self.dwell_calibrated) and not (self.held_back and self.dwell):
            raise SettingError(
                "{0} and {1} set the held-back rule's dwell: not with {2} or {3}",
                "dwell_draw",
                "dwell_calibrated",
                ("held_back", False),
                ("dwell", False),
            )
        if self.lag_draw and self.lag_calibrated:
            raise SettingError("{0} and {1}: choose one", "lag_draw", "lag_calibrated")
        if (self.lag_draw or self.lag_calibrated) and not self.held_back:
            raise SettingError(
                "{0} and {1} set the held-back rule's headways: not with {2}",
                "lag_draw",
                "lag_calibrated",
                ("held_back", False),
            )
        if not 0 <= self.dwell_percentile <= 100:
            raise SettingError(f"{{0}} {self.dwell_percentile:g}: give a percentile from 0 to 100", "dwell_percentile")
        if self.lanes not in LANES:
            raise SettingError(f"{{0}} {self.lanes}: a SUMO highway has {' or '.join(map(str, LANES))} lanes", "lanes")
        if not 0 < self.minutes <= 120:
            raise SettingError("{0} must be more than 0 and at most 120", "minutes")
