"""Robots carried by a person: the drag schedule of the plant (:class:`Carries`).

A drag carries robot ``i`` from ``t0`` for ``duration`` seconds: its position moves linearly by
``(dx_m, dy_m)`` from where the wheels left it at ``t0``, its heading is kept and its wheels have
no effect on the pose meanwhile (the motors keep running in the air). After the drag the wheels
act again. A step that straddles the start or the end of a drag is split exactly: wheels before,
carried in between, wheels after (:meth:`Carries.advance`). Pure numpy; time is passed in.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from sim_plant.core.kinematics import FloatArray

__all__ = ["Carries", "WheelsMove"]

BoolArray = npt.NDArray[np.bool_]

# Sim time is a float sum of steps; events this close to a step boundary happen at it.
_TIME_EPS_S = 1e-9

WheelsMove = Callable[[FloatArray, FloatArray | float, FloatArray, FloatArray], FloatArray]
"""``move(pose, a_s, b_s, span_s)``: the poses after the wheels act from ``a_s`` to ``b_s``
seconds into the step (``span_s = b_s - a_s`` per robot); the plant's motor lag and kinematics."""


class Carries:
    """The pending and running drags of ``n`` robots (row ``i`` = robot ``i``)."""

    def __init__(self, n: int) -> None:
        self._t0: FloatArray = np.full(n, np.inf)  # +inf: no drag
        self._dur: FloatArray = np.zeros(n)
        self._d: FloatArray = np.zeros((n, 2))
        self._origin: FloatArray = np.zeros((n, 2))
        self._started: BoolArray = np.zeros(n, dtype=np.bool_)
        self._carried: BoolArray = np.zeros(n, dtype=np.bool_)
        self._any = False  # cache of np.isfinite(self._t0).any()

    @property
    def any(self) -> bool:
        """Whether any robot has a pending or running drag."""
        return self._any

    @property
    def carried(self) -> BoolArray:
        """Copy of the mask of robots being carried right now, ``(n,)`` bool."""
        return self._carried.copy()

    def schedule(self, i: int, t0_s: float, duration_s: float, dx_m: float, dy_m: float) -> None:
        """A drag of robot ``i`` from ``t0_s`` (replaces any drag of ``i``)."""
        self.clear(i)
        self._t0[i] = t0_s
        self._any = True
        self._dur[i] = duration_s
        self._d[i] = (dx_m, dy_m)

    def clear(self, mask: BoolArray | int) -> None:
        """End the drags of ``mask`` (a running one stops where it is)."""
        self._t0[mask] = np.inf
        self._dur[mask] = 0.0
        self._d[mask] = 0.0
        self._started[mask] = False
        self._carried[mask] = False

    def advance(
        self, pose: FloatArray, ta: float, tb: float, dt: float, move: WheelsMove
    ) -> FloatArray:
        """The poses at ``tb`` from ``pose`` at ``ta`` (``dt = tb - ta``), drags applied."""
        n = pose.shape[0]
        has = np.isfinite(self._t0)
        t0 = self._t0
        t1 = t0 + self._dur
        # 1) wheels act from ta until the drag starts (whole step for robots without a drag).
        pre = np.clip(np.minimum(tb, t0) - ta, 0.0, dt)
        pose = move(pose, 0.0, pre, pre)
        # 2) drags that begin inside this step pick up the robot where the wheels left it.
        starting = has & ~self._started & (t0 < tb)
        self._origin[starting] = pose[starting, :2]
        self._started |= starting
        active = has & self._started
        post = np.zeros(n)
        # A drag ending within _TIME_EPS_S after tb counts as ended (float sums of dt).
        finished = active & (t1 <= tb + _TIME_EPS_S)
        if active.any():
            dur = self._dur[active]
            t_end = np.minimum(tb, t1[active])
            frac = np.where(
                (dur > 0.0) & ~finished[active],
                np.clip((t_end - t0[active]) / np.where(dur > 0.0, dur, 1.0), 0.0, 1.0),
                1.0,
            )
            pose[active, :2] = self._origin[active] + frac[:, None] * self._d[active]
            # 3) wheels act again after the drag ends inside this step.
            post[active] = np.clip(tb - np.maximum(ta, t1[active]), 0.0, dt)
        if finished.any():
            moved = move(pose, dt - post, np.full(n, dt), post)
            pose[finished] = moved[finished]
            self.clear(finished)
        self._carried = active & ~finished
        self._any = bool(np.isfinite(self._t0).any())
        return pose

    def append(self) -> None:
        """A new robot (last row), not carried."""
        self._t0 = np.append(self._t0, np.inf)
        self._dur = np.append(self._dur, 0.0)
        self._d = np.vstack([self._d, np.zeros((1, 2))])
        self._origin = np.vstack([self._origin, np.zeros((1, 2))])
        self._started = np.append(self._started, False)
        self._carried = np.append(self._carried, False)

    def delete(self, i: int) -> None:
        """Robot ``i`` is gone; the rows after it move down one."""
        self._t0 = np.delete(self._t0, i)
        self._dur = np.delete(self._dur, i)
        self._d = np.delete(self._d, i, axis=0)
        self._origin = np.delete(self._origin, i, axis=0)
        self._started = np.delete(self._started, i)
        self._carried = np.delete(self._carried, i)
        self._any = bool(np.isfinite(self._t0).any())
