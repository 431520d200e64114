"""The virtual leader's state at one time (paper eqs 1-2): :class:`LeaderState`.

A module of its own so that it runs compiled with the coordinator's tick
(``coordinator/core/_accel.py``) while ``coordinator.core.trajectory``, which imports and
re-exports it, stays Python (docs/architecture.md). One state is made every coordinator tick (by
the trajectory's ``sample`` or the leader's step) and its fields are read by the slots (eqs 3-5),
the leader and the simulator's log.

Why it is not a ``frozen=True`` dataclass: mypyc builds a frozen dataclass through the
dataclass's own Python ``__init__`` (each field stored with ``object.__setattr__``: about 0.6 us
a state), and it could not unpickle one. Here the class is an ``eq`` dataclass with its own
``__init__``, made read-only by its ``__setattr__`` and ``__delattr__`` (the same
``FrozenInstanceError`` as a frozen dataclass's); compiled, ``__init__`` stores the fields
natively (about 35 ns from compiled code, 170 ns from Python), in pure Python through the slots'
descriptors (which do not go through ``__setattr__``). The same fields, equality, hash (over the
fields, as a frozen dataclass's), ``repr``, ``dataclasses.replace`` and pickling either way. A
compiled state holds its fields as floats (an ``int`` given is stored as the same float). Pure,
stdlib only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import FrozenInstanceError, dataclass
from types import MemberDescriptorType
from typing import Any, Final

__all__ = ["LeaderState"]


@dataclass(unsafe_hash=True, slots=True)
class LeaderState:
    """State of the virtual leader at time ``t`` (s).

    ``x``, ``y`` in m; ``theta`` heading in rad, wrapped to (-pi, pi]; ``v_mps`` speed along the
    heading (m/s); ``omega_radps`` heading rate (rad/s). Read-only (module docstring).
    """

    t: float
    x: float
    y: float
    theta: float
    v_mps: float
    omega_radps: float

    def __init__(
        self, t: float, x: float, y: float, theta: float, v_mps: float, omega_radps: float
    ) -> None:
        if _NATIVE:  # compiled: native stores (they do not call __setattr__)
            self.t = t
            self.x = x
            self.y = y
            self.theta = theta
            self.v_mps = v_mps
            self.omega_radps = omega_radps
        else:  # pure Python: the slots' descriptors (no __setattr__; 0.45 us, not 0.75)
            _SET_T(self, t)
            _SET_X(self, x)
            _SET_Y(self, y)
            _SET_THETA(self, theta)
            _SET_V(self, v_mps)
            _SET_OMEGA(self, omega_radps)

    def __setattr__(self, name: str, value: Any) -> None:
        raise FrozenInstanceError(f"cannot assign to field {name!r}")

    def __delattr__(self, name: str) -> None:
        raise FrozenInstanceError(f"cannot delete field {name!r}")

    def __reduce__(self) -> tuple[type[LeaderState], tuple[float, ...]]:
        return (
            LeaderState,
            (self.t, self.x, self.y, self.theta, self.v_mps, self.omega_radps),
        )

    @property
    def vx(self) -> float:
        """World-frame x velocity, m/s (eq 1)."""
        return self.v_mps * math.cos(self.theta)

    @property
    def vy(self) -> float:
        """World-frame y velocity, m/s (eq 2)."""
        return self.v_mps * math.sin(self.theta)


_DESCRIPTORS = [vars(LeaderState)[f.name] for f in dataclasses.fields(LeaderState)]
#: The fields are slots of a Python class (pure Python), not native attributes (compiled).
_NATIVE: Final = not all(isinstance(d, MemberDescriptorType) for d in _DESCRIPTORS)
# The slot descriptors' setters the pure class's __init__ stores with.
_SET_T, _SET_X, _SET_Y, _SET_THETA, _SET_V, _SET_OMEGA = (d.__set__ for d in _DESCRIPTORS)
