"""A node's fault counters (runtime.faults): every rejection counted by message and reason,
told to whoever else counts it, internal errors counted apart."""

from __future__ import annotations

from bus_schemas import DecodeError, Reason, Status, decode
from runtime.faults import Faults
from runtime.log import NodeLog


def test_rejects_are_counted_by_message_and_reason() -> None:
    told: list[str] = []
    faults = Faults(NodeLog("test", min_interval_s=60.0), on_reject=told.append)
    bad = decode(b"\xc1", Status)
    assert isinstance(bad, DecodeError) and bad.reason is Reason.MALFORMED
    faults.reject("status", bad)
    faults.reject("pose", "robot 'r9' on r1's key", "misaddressed")
    faults.reject("host wheels", "no reason given")
    assert faults.rejects.as_dict() == {
        "host_wheels-invalid": 1,
        "pose-misaddressed": 1,
        f"status-{Reason.MALFORMED}": 1,
    }
    assert faults.rejected == 3 and faults.internal_errors == 0
    assert told[1] == "pose: robot 'r9' on r1's key" and len(told) == 3


def test_internal_errors_are_counted_apart() -> None:
    faults = Faults(NodeLog("test", min_interval_s=60.0))
    for _ in range(3):
        faults.internal("step", RuntimeError("boom"))
    assert faults.internal_errors == 3 and faults.rejected == 0
