"""``formation echo KEY``: a key's messages, decoded (formation.operate.bus_look)."""

from formation.operate.bus_look import echo_main as main

__all__ = ["main"]
