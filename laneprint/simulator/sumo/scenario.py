"""The files of one SUMO run: a straight road of `n_lanes` lanes and the vehicle types.

One edge `road` from x = 0, two or three lanes (index 0 = right), edge speed = the
section's limit. Vehicle types: `ego` (the driver's style, with the family's
car-following model), `car` and `truck` (background, Krauss, LC2013 or on sublanes SL2015; their desired speed
is set per vehicle, so their `speedFactor` is high and their `maxSpeed` above any
desired speed; dawdling `background_sigma`, 0 in the default family).
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

from laneprint.simulator.sumo.backend import run_netconvert
from laneprint.simulator.sumo.settings import SumoSettings

EDGE = "road"
ROUTE = "r"
EGO_TYPE = "ego"
CAR_TYPE = "car"
TRUCK_TYPE = "truck"
#: background vehicles return to the right lane within seconds (SUMO's legacy default waits ~7 s per m/s)
_BG_LC = {"lcKeepRightAcceptanceTime": 6.0}
#: background vehicles on sublanes: SL2015, centred in their lane (they keep it unless they change)
_BG_SUBLANE = {"laneChangeModel": "SL2015", "latAlignment": "center"}
_MAX_SPEED_MPS = 60.0  # [m/s] vType maxSpeed: above every desired speed (departSpeed must stay below it)
_EMERGENCY_DECEL_MPS2 = 9.0  # [m/s^2] SUMO's default for passenger cars; never below the driver's decel


def road_length_m(settings: SumoSettings, limit_kph: float) -> float:
    """Edge length: the ego at 1.5 x the limit for the whole section, plus margins [m]."""
    return round(
        settings.ego_start_m + 1.5 * limit_kph / 3.6 * (settings.duration_s + 60.0) + settings.road_margin_m, -2
    )


def _attrs(values: dict[str, object]) -> str:
    return " ".join(f"{k}={quoteattr(str(v))}" for k, v in values.items())


def routes_xml(ego_params: dict[str, float], settings: SumoSettings) -> str:
    """The route file: vehicle types and the single route (vehicles are added at run time)."""
    ego = {
        "id": EGO_TYPE,
        "vClass": "passenger",
        "length": settings.ego_length_m,
        "maxSpeed": _MAX_SPEED_MPS,
        "speedDev": 0,
        "carFollowModel": settings.car_follow_model,
        "laneChangeModel": settings.lane_change_model,
        "emergencyDecel": max(_EMERGENCY_DECEL_MPS2, ego_params.get("decel", 0.0)),
        **ego_params,
    }
    car = {
        "id": CAR_TYPE,
        "vClass": "passenger",
        "length": 4.5,
        "maxSpeed": _MAX_SPEED_MPS,
        "speedFactor": 2.0,
        "speedDev": 0,
        "sigma": settings.background_sigma,
        "tau": 1.0,
        "accel": 2.6,
        "decel": 4.5,
        **_BG_LC,
    }
    truck = {
        "id": TRUCK_TYPE,
        "vClass": "passenger",
        "length": 12.0,
        "maxSpeed": _MAX_SPEED_MPS,
        "speedFactor": 2.0,
        "speedDev": 0,
        "sigma": settings.background_sigma,
        "tau": 1.2,
        "accel": 1.0,
        "decel": 4.0,
        **_BG_LC,
    }
    if settings.lateral_resolution_m > 0:  # sublanes: the traffic changes lanes with SL2015 too
        car = {**car, **_BG_SUBLANE}
        truck = {**truck, **_BG_SUBLANE}
    lines = ["<routes>"] + [f"    <vType {_attrs(t)}/>" for t in (ego, car, truck)]
    lines += [f'    <route id="{ROUTE}" edges="{EDGE}"/>', "</routes>", ""]
    return "\n".join(lines)


def build_network(folder: Path, settings: SumoSettings, limit_kph: float) -> Path:
    """Write the section's network into `folder` (via netconvert); its path."""
    length = road_length_m(settings, limit_kph)
    stem = f"road{int(round(limit_kph))}"
    nodes, edges = folder / f"{stem}.nod.xml", folder / f"{stem}.edg.xml"
    nodes.write_text(f'<nodes>\n    <node id="a" x="0" y="0"/>\n    <node id="b" x="{length:.0f}" y="0"/>\n</nodes>\n')
    edges.write_text(
        f'<edges>\n    <edge id="{EDGE}" from="a" to="b" numLanes="{settings.n_lanes}" speed="{limit_kph / 3.6:.6f}" '
        f'width="{settings.lane_width_m}"/>\n</edges>\n'
    )
    return run_netconvert(nodes, edges, folder / f"{stem}.net.xml")


def write_routes(path: Path, ego_params: dict[str, float], settings: SumoSettings) -> Path:
    """Write the route file (vehicle types, the route) to `path`."""
    path.write_text(routes_xml(ego_params, settings))
    return path
