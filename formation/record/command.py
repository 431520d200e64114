"""``formation record``: record every key of a fleet (and its liveliness changes) to MCAP.

Usage::

    formation record --out run.mcap [--fleet demo] [--duration S] [--raw] [--no-derived]
                     [--endpoint tcp/127.0.0.1:7447 ...]

Prints one line ``recording formation/<fleet>/** to <file>`` once subscribed, runs until
SIGINT/SIGTERM or ``--duration`` seconds, finalizes the file (summary, statistics, index) and
exits 0. A file that cannot be written or finalized (a full or read-only disk) stops the
writing, not the recording's end: it is closed as far as it got, one line says why and how
many observations were not written, and the exit status is 1. ``formation up --record FILE``
calls :func:`start_recorder` for the same result.

What the file holds (docs/observability.md has the full channel list)
---------------------------------------------------------------------
* One channel per bus key, topic ``/<key>`` (``/formation/demo/robot/r1/pose``), message encoding
  ``json``, schema encoding ``jsonschema``, schema name ``formation.<Type>`` (``formation.Pose``).
  The JSON Schemas are generated from the declarative message tables of ``bus_schemas``
  (:func:`json_schema`), so the bus contract stays the single source. A message is written as
  the map that was on the wire (unknown extra fields kept) after the strict ``bus_schemas``
  validation passed; one that fails it goes to ``/recorder/rejected`` with the reason and the
  payload in base64.
* Liveliness: one channel per token key (``/formation/demo/alive/robot/r1``), schema
  ``formation.Liveliness``, one message ``{alive: true|false, ...}`` per appearance/disappearance
  (the tokens already alive when recording starts are written as ``alive: true`` at once).
* Derived channels Foxglove can plot without code: ``/derived/robot/<id>/tracking_error``
  (``norm_m`` = hypot(ex, ey) of the agent's status, eqs 17-18) and
  ``/derived/robot/<id>/latency`` (pose-to-wheels latency, see :class:`LatencyTracker`).
* ``/scene`` (``foxglove.SceneUpdate``) and ``/tf`` (``foxglove.FrameTransforms``), protobuf, at
  5 Hz of receive time: the 3D view of ``formation.live.foxglove`` (robots, slots, leader-follower
  links),
  when foxglove-sdk is installed.
* With ``--raw``: the exact payload bytes as well, topic ``/raw/<key>``, encoding ``msgpack``
  (no schema; Foxglove cannot decode these, ``formation report`` prefers them when present).

Times: ``log_time`` is the receive time at the recorder, in ns of the wall clock (derived from
``time.monotonic_ns()`` plus one fixed offset taken at start, so differences between log times
are exact monotonic differences and the file shows real dates in Foxglove). ``publish_time`` is
the message's ``t`` in ns (sim time in lockstep, the publisher's monotonic clock in realtime);
``log_time`` for liveliness and derived records. The metadata record ``formation.recording``
holds the two clock anchors, so ``log_time`` can be mapped back to this host's monotonic clock.

Threading: Zenoh calls the subscriber callbacks on its own threads; they only copy the sample
into a bounded queue (:class:`BusTap`). One writer thread decodes and writes, so the MCAP writer
is only ever used by that thread. A full queue drops the sample and counts it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Final

import zenoh

import runtime as rt
from bus_schemas import keys
from formation.outputs.bus_json import json_schema
from formation.record.writer import (
    DEFAULT_CHUNK_BYTES,
    LIBRARY,
    METADATA_NAME,
    RAW_PREFIX,
    REJECTED_TOPIC,
    RUN_METADATA_NAME,
    STATS_METADATA_NAME,
    Recorder,
    RecorderStats,
)
from runtime.tap import BusTap

__all__ = [
    "DEFAULT_CHUNK_BYTES",
    "LIBRARY",
    "METADATA_NAME",
    "RAW_PREFIX",
    "READY_PREFIX",
    "REJECTED_TOPIC",
    "RUN_METADATA_NAME",
    "STATS_METADATA_NAME",
    "Recorder",
    "RecorderHandle",
    "RecorderStats",
    "build_parser",
    "incomplete",
    "json_schema",
    "main",
    "run_info",
    "start_recorder",
]

READY_PREFIX: Final = "recording "
"""Start of the line ``formation record`` prints on stdout once it is subscribed."""

# --------------------------------------------------------------------------------------------
# The recorder
# --------------------------------------------------------------------------------------------


def incomplete(path: str | Path, stats: RecorderStats) -> str:
    """The line naming a recording that could not be written whole (``stats.error``)."""
    return (
        f"recording {path} is incomplete: {stats.error}; {stats.unwritten} observations not "
        "written, the file is not finalized (no summary or footer)"
    )


def run_info(
    scenario: str | None = None,
    *,
    lockstep: bool | None = None,
    settle_s: float | None = None,
    **extra: object,
) -> dict[str, str]:
    """What a recording should know about its run, for ``formation report``.

    ``scenario`` is a built-in name or a TOML file: its text is embedded (``scenario_toml``), so
    the report rebuilds the run's robots, slots, geometry and settling band without the file.
    ``lockstep`` and ``settle_s`` are what the live run used; ``extra`` (seed, duration_s, ...)
    is stored as text. Raises ``ScenarioError`` if the scenario cannot be read.
    """
    out: dict[str, str] = {}
    if scenario is not None:
        import scenario as scenario_mod

        path = scenario_mod.resolve(scenario)
        out["scenario"] = scenario
        out["scenario_toml"] = path.read_text(encoding="utf-8")
    if lockstep is not None:
        out["lockstep"] = "true" if lockstep else "false"
    if settle_s is not None:
        out["settle_s"] = repr(float(settle_s))
    for name, value in extra.items():
        out[name] = str(value)
    return out


class RecorderHandle:
    """What :func:`start_recorder` returns: ``.close()`` stops and finalizes (idempotent)."""

    def __init__(
        self, recorder: Recorder, tap: BusTap, own_session: zenoh.Session | None = None
    ) -> None:
        self.recorder = recorder
        self.tap = tap
        self._own_session = own_session

    @property
    def path(self) -> Path:
        """The MCAP file being written."""
        return self.recorder.path

    def close(self) -> RecorderStats:
        """Stop recording and finalize the file; closes the session if the handle opened it."""
        stats = self.recorder.close()
        if self._own_session is not None and not self._own_session.is_closed():
            self._own_session.close()
        return stats


def start_recorder(
    session_or_settings: zenoh.Session | rt.ZenohSettings,
    fleet: str,
    path: str | Path,
    *,
    raw: bool = False,
    derived: bool = True,
    run: Mapping[str, str] | None = None,
) -> RecorderHandle:
    """Start recording ``formation/<fleet>/**`` and its liveliness to the MCAP file ``path``.

    Given a session, the recorder subscribes on it (the caller keeps owning the session and
    must call ``handle.close()`` before closing it). Given :class:`ZenohSettings`, it opens its
    own session and closes it in ``handle.close()``. ``run`` (see :func:`run_info`) is stored as
    the ``formation.run`` metadata record. Returns once subscribed; raises ``OSError`` if the file
    cannot be created, ``TransportError`` if the session cannot open.

    ``formation up --record FILE`` calls it on its own session right after subscribing its
    collector::

        handle = start_recorder(session, fleet, path, run=run_info(
            plan.scenario_arg, lockstep=cfg.lockstep, settle_s=plan.settle_s, seed=plan.seed))
        ...
        handle.close()   # before session.close()
    """
    own: zenoh.Session | None = None
    if isinstance(session_or_settings, rt.ZenohSettings):
        own = rt.open_session(session_or_settings)
        session = own
    else:
        session = session_or_settings
    try:
        recorder = Recorder(path, fleet, raw=raw, derived=derived, run=run)
        tap = recorder.attach(session)
    except BaseException:
        if own is not None:
            own.close()
        raise
    return RecorderHandle(recorder, tap, own)


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The ``formation record`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation record",
        description="Record every key of a fleet and its liveliness changes to an MCAP file "
        "(JSON channels with JSON Schemas; open it in Foxglove or run `formation report`).",
    )
    p.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    p.add_argument(
        "--fleet",
        default=None,
        help="fleet name (default: $FORMATION_FLEET, else the running `formation up`'s, else demo)",
    )
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    p.add_argument("--raw", action="store_true", help="also keep the msgpack payloads")
    p.add_argument("--no-derived", action="store_true", help="skip the /derived/ channels")
    p.add_argument(
        "--scenario",
        default=None,
        help="scenario of the run (name or TOML file), embedded for `formation report`",
    )
    rt.add_zenoh_arguments(p)
    return p


def main(argv: list[str]) -> int:
    """``formation record``: exit 0 after a clean stop, 1 if the session cannot open."""
    args = build_parser().parse_args(argv)
    from formation.outputs.runfile import resolve_target

    resolve_target(args)  # --endpoint / --fleet not given: $FORMATION_*, the running fleet
    try:
        keys.check_fleet(args.fleet)
    except ValueError as exc:
        print(f"formation record: {exc}", file=sys.stderr)
        return 2
    if args.duration is not None and not args.duration > 0:
        print("formation record: --duration must be > 0", file=sys.stderr)
        return 2
    try:
        run = run_info(args.scenario) if args.scenario is not None else None
    except ValueError as exc:  # ScenarioError
        print(f"formation record: {exc}", file=sys.stderr)
        return 2
    from formation.outputs.runfile import tool_settings  # a --secure run: its observer credentials

    settings = tool_settings(args, "observer")

    async def node(stop: asyncio.Event) -> int:
        try:
            session = await rt.open_session_async(settings)
        except rt.TransportError as exc:
            print(f"formation record: {exc}", file=sys.stderr)
            return 1
        recorder: Recorder | None = None
        code = 0
        try:
            recorder = Recorder(
                args.out, args.fleet, raw=args.raw, derived=not args.no_derived, run=run
            )
            recorder.attach(session)
            print(f"{READY_PREFIX}{keys.fleet_pattern(args.fleet)} to {args.out}", flush=True)
            with contextlib.suppress(TimeoutError):  # --duration elapsed
                await asyncio.wait_for(stop.wait(), timeout=args.duration)
        finally:
            if recorder is not None:
                # Finalizing takes milliseconds; run it off the loop so a signal still lands.
                stats = await asyncio.to_thread(recorder.close)
                print(
                    f"recorded {stats.samples} samples ({stats.rejected} rejected, "
                    f"{stats.liveliness} liveliness changes) to {args.out}",
                    flush=True,
                )
                if stats.error is not None:  # a full or read-only disk: say so, exit 1
                    print(f"formation record: {incomplete(args.out, stats)}", file=sys.stderr)
                    code = 1
            session.close()
        return code

    return rt.run_node(node, grace_s=0.8, hard_exit_s=3.0)
