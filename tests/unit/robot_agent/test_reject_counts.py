"""Every drop counted by reason (issue 13 items 4 and 8), on the Zenoh-free node classes."""

from __future__ import annotations

from typing import Any

import runtime as rt
from bus_schemas import Estop, Heartbeat, Pose, encode, keys
from coordinator.node.coordinator import CoordinatorNode
from robot_agent.node.agent import AgentNode
from scenario import load

SCN = load("paper-exp2")


def sink() -> tuple[list[tuple[str, bytes]], Any]:
    out: list[tuple[str, bytes]] = []
    return out, lambda key, payload, qos: out.append((key, payload))


def test_agent_counts_quarantine_drops_and_bad_input_by_reason() -> None:
    _, publish = sink()
    node = AgentNode("r1", "demo", SCN.agent, publish)
    pose = encode(Pose(t=1.0, seq=1, x=0.0, y=0.0, theta=0.0, robot="r1"))
    node.stall.turned(100.0)
    # a stop (gap > 0.5 s, no SIGCONT watching in this test): the backlog is dropped, counted
    node.on_pose(rt.Received(keys.pose_key("demo", "r1"), pose, 101.0))
    node.on_pose(rt.Received(keys.pose_key("demo", "r1"), pose, 101.1))
    node.stall.turned(101.9)  # the loop turns again after the quarantine (0.25 s)
    node.on_pose(rt.Received(keys.pose_key("demo", "r1"), b"\x01garbage", 102.0))
    other = encode(Pose(t=1.0, seq=1, x=0.0, y=0.0, theta=0.0, robot="r2"))
    node.on_pose(rt.Received(keys.pose_key("demo", "r1"), other, 102.1))
    counts = node.faults.rejects.as_dict()
    assert counts["pose-quarantine"] == 2 and counts["pose-misaddressed"] == 1, counts
    assert node.faults.rejects.total == 4, counts
    st = node.status_message(102.2)
    assert st.rejected == 4 and st.rejects is not None and sum(st.rejects.values()) == 4


def test_agent_estop_scopes_and_query_answers() -> None:
    _, publish = sink()
    node = AgentNode("r1", "demo", SCN.agent, publish, lockstep=True)
    key = keys.estop_key("demo")

    def estop(engage: bool, robot: str | None, eid: int | None = None) -> None:
        msg = Estop(t=1.0, engage=engage, robot=robot, id=eid)
        node.on_estop(rt.Received(key, encode(msg), 0.0))

    def latched() -> bool:
        return node.firmware.status().estop_latched

    estop(True, None)
    estop(False, "r1")
    assert latched()  # r1's release does not clear the fleet's
    estop(False, None)
    assert not latched()
    estop(True, "r1")
    estop(False, None)
    assert latched()  # the fleet's release does not clear r1's
    estop(False, "r1")
    assert not latched()
    # a query answer (a coordinator's latched state) stops a robot that missed the message
    node.on_estop_state([(True, None, 7)])
    assert latched()
    # an answer that does not mention the engagement releases nothing (robot_agent.core.estop) ...
    node.on_estop_state([(False, None, None)])
    assert latched()
    # ... one that saw that engagement released does
    node.on_estop_state([(False, None, None), (False, None, 7)])
    assert not latched()
    # an engagement released here is not added back by an older answer
    estop(True, None, 8)
    estop(False, None)
    node.on_estop_state([(True, None, 8)])
    assert not latched()
    # one without an id (an older coordinator) is held until a release message
    node.on_estop_state([(True, None, None)])
    node.on_estop_state([(False, None, None)])
    assert latched()
    estop(False, None)
    assert not latched()
    node.on_estop_state([])  # no answer: nothing changes
    assert not latched()


def test_coordinator_counts_heartbeat_refusals_by_reason() -> None:
    _, publish = sink()
    node = CoordinatorNode(SCN, "main", "demo", publish)
    key = keys.heartbeat_key("demo", "zz")
    hb = Heartbeat(t=1.0, seq=1, name="zz", active=True, epoch=5, leader_t0=0.0)
    node.election_io.on_heartbeat(rt.Received(key, encode(hb), 1.0))  # no token
    node.election_io.on_heartbeat(rt.Received(key, b"\xc1", 1.0))  # not msgpack
    st = node.status_map(1.0)
    assert st["rejected"] == 2 and sum(st["rejects"].values()) == 2
    assert st["rejects"]["heartbeat-no_token"] == 1 and node.active
    # the latched e-stop state answers queries
    node.on_estop(
        rt.Received(keys.estop_key("demo"), encode(Estop(t=1.0, engage=True, robot="r2")), 1.0)
    )
    assert len(node.estop_answer) == 2 and node.status(1.0).estop_robots == ("r2",)


def test_faults_count_by_message_and_reason_and_log_rate_limited(capsys: Any) -> None:
    """runtime.Faults, the one counter every shell owns: ``<message>-<reason>`` keys (a
    DecodeError's reason, else the given one, else ``invalid``; spaces become ``_``), internal
    errors apart, one log line per topic however many drops (NodeLog.limited)."""
    from bus_schemas import DecodeError, Reason, decode

    faults = rt.Faults(rt.NodeLog("test", min_interval_s=3600.0))
    err = decode(b"\x01garbage", Pose)
    assert isinstance(err, DecodeError)
    for _ in range(3):
        faults.reject("pose", err)
    faults.reject("host wheels", "no robot")
    faults.reject("pose", "stale", reason="stale")
    faults.internal("on_pose", ValueError("boom"))
    assert faults.rejects.as_dict() == {
        f"pose-{Reason(err.reason)}": 3,
        "host_wheels-invalid": 1,
        "pose-stale": 1,
    }
    assert faults.rejected == 5 and faults.internal_errors == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 3, lines  # reject-pose once, reject-host wheels, internal-on_pose
    assert lines[-1] == "test: internal error in on_pose: ValueError('boom')"
