"""``formation ls``: the fleets on a router (formation.operate.bus_look)."""

from formation.operate.bus_look import ls_main as main

__all__ = ["main"]
