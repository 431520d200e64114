"""The robot's firmware mode: the one declaration of ``Mode``, shared by the contract (the status
and command messages carry it) and the firmware core (``robot_agent.core``, whose mode machine
is in its ``firmware_modes.py``).

Standard library only: the firmware core may import it (tests/repo/test_agent_imports.py checks
that every contract module the core imports stays so).
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["Mode"]


class Mode(StrEnum):
    """Mode of a robot agent's firmware state machine; the value is what the status message
    carries. The meaning of each mode and the transitions: robot_agent/core/firmware_modes.py.
    """

    IDLE = "idle"
    TRACKING = "tracking"
    HOLD = "hold"
    ESTOP = "estop"
