"""Checks of the e-stop path shared by the e-stop tests: a source that rejects every request
(:func:`rejecting_source`), the answer to a query (:func:`answer_of`) and a robot stopped with
zero wheels (:func:`assert_stopped`)."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
import zenoh

import runtime as rt
from bus_schemas import (
    Estop,
    decode_or_raise,
)
from coordinator.node.estop_source import EstopSource
from runtime.query import get_all
from support.agent_io import nonzero
from support.bus_watch import Recorder


def rejecting_source(rejects: list[str]) -> EstopSource:
    return EstopSource(
        "formation/demo/estop",
        lambda: 1.0,
        lambda what, why, reason=None: rejects.append(f"{what}: {why}"),
        lambda where, exc: rejects.append(f"internal {where}: {exc!r}"),
        rt.NodeLog("test"),
    )


def assert_stopped(
    wheels: Recorder,
    status: Recorder,
    t0: float,
    t1: float,
    *,
    min_wheels: int,
    min_status: int,
) -> None:
    """Between receive times ``t0`` and ``t1`` the agent published wheels and status (at least
    that many), every wheel command zero and every status in mode ESTOP."""
    held_wheels = [w for r, _k, w in wheels.snapshot() if t0 < r < t1]
    held_status = [s for r, _k, s in status.snapshot() if t0 < r < t1]
    assert len(held_wheels) > min_wheels and len(held_status) >= min_status
    moving = [w for w in held_wheels if nonzero(w)]
    assert not moving, f"{len(moving)} non-zero wheels without a release: {moving[:3]}"
    assert {s.mode for s in held_status} == {"estop"}


def answer_of(
    client: zenoh.Session,
    key: str,
    ok: Callable[[list[Estop]], bool],
    timeout_s: float = 5.0,
) -> list[Estop]:
    """The answer on ``key`` once ``ok`` says it is the expected one (a queryable declared just
    before a process said "ready" may reach the router after the test's first query: a
    starved process sends its declarations late)."""
    deadline = time.monotonic() + timeout_s
    while True:
        answer = [decode_or_raise(p, Estop) for p in get_all(client, key, 1.0)]
        if ok(answer):
            return answer
        if time.monotonic() > deadline:
            pytest.fail(f"{key}: {answer}")
        time.sleep(0.05)
