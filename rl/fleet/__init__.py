"""Fleets: many agents (one per driver or style and seed) trained together, each in its own run folder."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "FleetTrainer": "rl.fleet.batch",
        "create_fleet": "rl.fleet.runs",
        "train_fleet": "rl.fleet.runs",
        "list_fleets": "rl.fleet.store",
        "load_fleet": "rl.fleet.store",
        "fleet_table": "rl.fleet.store",
    },
)
