"""What a ``formation up`` launcher reads of its fleet: its Zenoh session(s), the subscriptions
that feed the run's :class:`~formation.record.collector.RunCollector`, and the receive times of
the first and the latest truth frame (a realtime run's duration counts from the first).

:class:`RunIntake` owns all of it. It opens its session only after every child was spawned (no
fork after Zenoh), drains the samples into the collector every :data:`CONSUME_PERIOD_S` (and
only then: a sample does not wake the launcher's loop), and at the end of a lockstep run waits
for the plant's last tick to be complete (a condition, not a time)."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from typing import Any, Final

from bus_schemas import keys
from formation.launch.plan import UpConfig
from formation.record.collector import RunCollector, key_patterns
from scenario import Scenario

__all__ = ["RunIntake"]

DRAIN_S: Final = 0.25
"""Lockstep: time given to the last messages in flight after the plant ended, seconds."""
LOCKSTEP_DRAIN_MAX_S: Final = 30.0
"""Lockstep: how long (wall s) the launcher waits, after the plant ran its duration, for the
plant's last tick to reach the collector (an overloaded machine can hold samples for seconds)."""
FIFO_CAPACITY: Final = 1 << 14
"""Samples buffered per collector key expression (the inbox holds this many per pattern, drained
every CONSUME_PERIOD_S): a bound on the launcher's memory (each sample is at most
runtime.transport.MAX_MESSAGE_BYTES); a 300-robot batched fleet puts ~10 samples per key
expression in one period. Overflow drops the oldest and counts (``inbox.dropped``)."""
COLLECTOR_MAX_ENTRIES: Final = 1_500_000
"""Realtime: values the collector keeps before it thins the run's history
(formation.record.collector, ``max_entries``; ~200 MiB at most). 300 robots fill it in ~30 s,
10 robots in ~50 min."""
CONSUME_PERIOD_S: Final = 0.02
_TRUTH_LEAVES: Final = (f"/{keys.TRUTH}", f"/{keys.TRUTHS}")  # per robot, or batched


class RunIntake:
    """The launcher's sessions and the collector they feed (``secure``: the run's
    :class:`formation.launch.pki.RunConfigs` with ``--secure``, else None)."""

    def __init__(self, cfg: UpConfig, scn: Scenario) -> None:
        self.cfg = cfg
        self.collector = RunCollector.for_scenario(
            scn, fleet=cfg.fleet, lockstep=cfg.lockstep, max_entries=COLLECTOR_MAX_ENTRIES
        )
        self.session: Any = None
        self._operator_session: Any = None  # --secure --foxglove: the live view's commands
        self._inbox: Any = None  # runtime.Inbox("queue") of the collector's samples
        self._subscribers: list[Any] = []
        self.first_truth_rx: float | None = None
        self.last_truth_rx: float | None = None

    def truth_rx(self) -> tuple[float | None, float | None]:
        """When the first and the latest truth frame were received (this host's monotonic s)."""
        return self.first_truth_rx, self.last_truth_rx

    def run_wall_s(self) -> float | None:
        """Wall seconds from the first to the latest truth frame (None before two)."""
        if self.first_truth_rx is None or self.last_truth_rx is None:
            return None
        return self.last_truth_rx - self.first_truth_rx

    def ran_s(self) -> float:
        """Wall seconds since the first truth frame (0 before it)."""
        return 0.0 if self.first_truth_rx is None else time.monotonic() - self.first_truth_rx

    async def open(self, secure: Any) -> None:
        """Open the session (as the observer identity with ``--secure``: the launcher reads the
        whole fleet) and subscribe the collector to the fleet's keys and liveliness."""
        import runtime as rt

        loop = asyncio.get_running_loop()
        if secure is None:
            settings = rt.ZenohSettings(connect=(self.cfg.endpoint,), open_timeout_s=5.0)
        else:
            settings = rt.ZenohSettings(
                connect=(),
                mode=None,
                config_file=str(secure.clients["observer"]),
                open_timeout_s=5.0,
            )
        self.session = await rt.open_session_async(settings)
        # The one bridge (runtime.bridge) into a queue inbox that the loop drains every
        # CONSUME_PERIOD_S, and only then (wake=False): a sample does not wake the launcher's
        # loop, so on two cores the launcher takes less from the lockstep it is watching and
        # from the control loop of a realtime fleet (each agent host's batch of wheels used to
        # wake it once, in the middle of the host's next batch).
        patterns = key_patterns(self.cfg.fleet, lockstep=self.cfg.lockstep)
        self._inbox = rt.Inbox("queue", maxlen=FIFO_CAPACITY * len(patterns), wake=False)
        self._subscribers = [rt.subscribe(self.session, p, loop, self._inbox) for p in patterns]
        rt.watch_liveliness(
            self.session, keys.alive_pattern(self.cfg.fleet), loop, self.collector.feed_alive
        )

    def subscribe(self, key: str, on_payload: Callable[[bytes], None]) -> None:
        """One more subscription on the session, handled on the loop (the scripted faults')."""
        import runtime as rt

        loop = asyncio.get_running_loop()
        sub = rt.subscribe(self.session, key, loop, lambda rx: on_payload(rx.payload))
        self._subscribers.append(sub)

    async def commands_session(self, secure: Any) -> Any:
        """The session a ``--foxglove`` client's publishes are put with (issue 28): the
        launcher's own; with ``--secure`` one as the operator identity (the router admits the
        operator's commands from it only). None without ``--foxglove``."""
        import runtime as rt

        if self.cfg.foxglove_port is None:
            return None
        if secure is None:
            return self.session
        settings = rt.ZenohSettings(
            connect=(),
            mode=None,
            config_file=str(secure.clients["operator"]),
            open_timeout_s=5.0,
        )
        self._operator_session = await rt.open_session_async(settings)
        return self._operator_session

    def drain(self) -> None:
        """Feed every sample the inbox holds to the collector."""
        if self._inbox is None:
            return
        feed = self.collector.feed
        for rx in self._inbox.drain():
            key = rx.key
            if feed(key, rx.payload) and key.endswith(_TRUTH_LEAVES):
                # when Zenoh's thread received it, not when this (niced) loop drained it
                now = rx.rx_s
                if self.first_truth_rx is None:
                    self.first_truth_rx = now
                self.last_truth_rx = now

    async def consume(self) -> None:
        """Drain every :data:`CONSUME_PERIOD_S`, until cancelled."""
        while True:
            self.drain()
            await asyncio.sleep(CONSUME_PERIOD_S)

    async def first_truth(self) -> None:
        """Return once the first truth frame was received."""
        while self.first_truth_rx is None:
            await asyncio.sleep(0.02)

    async def drain_lockstep(self, duration_s: float, warn: Callable[[str], None]) -> None:
        """Lockstep, after the plant ran ``duration_s``: wait until the collector holds the
        plant's last tick, its truth and the answers to it (``RunCollector.tick_complete``: a
        condition, not a time: the result of a lockstep run must not depend on how loaded the
        machine is), then :data:`DRAIN_S` for the other nodes' last samples (status).
        Bounded by :data:`LOCKSTEP_DRAIN_MAX_S`; a run cut short says how many ticks it lacks."""
        dt = self.collector.dt_s
        final = None if dt is None else round(duration_s / dt)
        deadline = time.monotonic() + LOCKSTEP_DRAIN_MAX_S
        while final is not None:
            self.drain()
            if self.collector.tick_complete(final):
                break
            if time.monotonic() > deadline:
                last = self.collector.last_truth_tick
                warn(
                    f"the plant's last tick {final} (its truth and answers) did not reach the "
                    f"collector within "
                    f"{LOCKSTEP_DRAIN_MAX_S:g} s (last: {last}): the metrics end early"
                )
                break
            await asyncio.sleep(CONSUME_PERIOD_S)
        await asyncio.sleep(DRAIN_S)  # the other nodes' last messages may be in flight

    @property
    def dropped(self) -> int:
        """Samples the inbox dropped (it overflowed)."""
        return 0 if self._inbox is None else int(self._inbox.dropped)

    async def take_last(self) -> None:
        """At the end, after the nodes stopped: what the bridge handed over goes to the
        collector; no sample is taken after this (the subscriptions are dropped)."""
        await asyncio.sleep(0)  # the inbox takes what the bridge handed over
        try:
            self.drain()  # what arrived before the nodes stopped
        finally:
            self._subscribers = []

    def close(self) -> None:
        """Close the sessions (never raises)."""
        with contextlib.suppress(Exception):
            if self._operator_session is not None:
                self._operator_session.close()
        with contextlib.suppress(Exception):
            if self.session is not None:
                self.session.close()
