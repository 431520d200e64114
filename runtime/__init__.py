"""The shared node runtime: everything a process shell needs around its pure core.

One floor above the contract (``bus_schemas``) and below the process shells (docs/architecture.md):

* :mod:`runtime.transport`: Zenoh settings, config, sessions, QoS, publishers;
* :mod:`runtime.bridge`: the one subscription bridge (Zenoh's network thread -> a loop
  callback in arrival order, an ``Inbox``, :mod:`runtime.tap`'s worker thread, or a lockstep
  node's ``TickPump``), liveliness tokens and watches;
* :mod:`runtime.lifecycle`: ``run_node`` (signals, bounded shutdown) and ``serve``, the one node
  bootstrap;
* :mod:`runtime.log` (``NodeLog``), :mod:`runtime.faults` (``Faults``: rejects and internal
  errors), :mod:`runtime.timers` (the agent timer loop),
  :mod:`runtime.args` (command-line value parsers and the checks after parsing: ``UsageError``),
  :mod:`runtime.stall` (stall/resume detection, a pure core), :mod:`runtime.sdnotify` (systemd
  notifications).

Everything is re-exported here, so a shell writes ``import runtime as rt`` and ``rt.serve``.
"""

from runtime.args import (
    USAGE_EXIT,
    UsageError,
    check_names,
    finite_or_none,
    load_fleet_file,
    load_scenario,
    non_negative_int,
    positive_float,
    rate_hz,
    zenoh_settings,
)
from runtime.bridge import (
    Inbox,
    LivelinessHandler,
    LoopFeed,
    Received,
    SampleHandler,
    TickPump,
    declare_token,
    loop_feed,
    subscribe,
    subscribe_on_thread,
    watch_liveliness,
    watch_liveliness_on_thread,
)
from runtime.faults import Faults
from runtime.lifecycle import FORCED_EXIT_CODE, NodeIO, NodeMain, run_node, serve, stop_signalled
from runtime.log import NodeLog
from runtime.stall import (
    HANG_GAP_NO_LEASE_S,
    HANG_GAP_S,
    RESUME_QUARANTINE_S,
    StallDetector,
    hang_gap_for,
)
from runtime.transport import (
    DEFAULT_ENDPOINT,
    MAX_MESSAGE_BYTES,
    QOS_CONTROL,
    QOS_CRITICAL,
    QOS_TELEMETRY,
    SESSION_CLOSE_S,
    Publishers,
    QoS,
    TransportError,
    ZenohSettings,
    add_zenoh_arguments,
    close_session,
    make_config,
    open_session,
    open_session_async,
    settings_from_args,
)

__all__ = [
    "DEFAULT_ENDPOINT",
    "FORCED_EXIT_CODE",
    "HANG_GAP_NO_LEASE_S",
    "HANG_GAP_S",
    "MAX_MESSAGE_BYTES",
    "QOS_CONTROL",
    "QOS_CRITICAL",
    "QOS_TELEMETRY",
    "RESUME_QUARANTINE_S",
    "SESSION_CLOSE_S",
    "USAGE_EXIT",
    "Faults",
    "Inbox",
    "LivelinessHandler",
    "LoopFeed",
    "NodeIO",
    "NodeLog",
    "NodeMain",
    "Publishers",
    "QoS",
    "Received",
    "SampleHandler",
    "StallDetector",
    "TickPump",
    "TransportError",
    "UsageError",
    "ZenohSettings",
    "add_zenoh_arguments",
    "check_names",
    "close_session",
    "declare_token",
    "finite_or_none",
    "hang_gap_for",
    "load_fleet_file",
    "load_scenario",
    "loop_feed",
    "make_config",
    "non_negative_int",
    "open_session",
    "open_session_async",
    "positive_float",
    "rate_hz",
    "run_node",
    "serve",
    "settings_from_args",
    "stop_signalled",
    "subscribe",
    "subscribe_on_thread",
    "watch_liveliness",
    "watch_liveliness_on_thread",
    "zenoh_settings",
]
