"""Names of the log format v1 (LOG_FORMAT.md): CSV columns, MCAP topics and message fields.

Shared by the writers and the readers so the two can never disagree.
"""

from __future__ import annotations

DEFAULT_LENGTH_M = 4.5  # [m] vehicle length when a log does not give one

# --- CSV -------------------------------------------------------------------

CSV_TIME = "t"
CSV_META = ("driver_id", "session_id", "speed_limit_kph", "simulator")
CSV_EGO_REQUIRED = ("ego_x", "ego_v", "ego_lane")
CSV_EGO_OPTIONAL = ("ego_y", "ego_length", "steer", "throttle", "brake", "lc_button", "lc_direction")
# vehicle column suffixes, in the order the writer emits them
CSV_VEHICLE_FIELDS = ("x", "v", "lane", "y", "length")

# --- MCAP ------------------------------------------------------------------

TOPIC_EGO = "/ego/state"
TOPIC_TRAFFIC = "/traffic/vehicles"
TOPIC_CONTROLS = "/driver/controls"
TOPIC_BUTTON = "/driver/lane_change_button"
METADATA_NAME = "session"

NS_PER_S = 1_000_000_000
