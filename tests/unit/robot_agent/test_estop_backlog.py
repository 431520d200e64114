"""An e-stop that reaches a starved agent in a backlog: the agent's handlers run in arrival order
(runtime.bridge), so wheels computed from inputs that arrived *before* the e-stop may still be
published late, but the step that takes the e-stop publishes zero wheels in ESTOP, and no wheels
message after it is non-zero, whatever else the backlog holds and whenever the timer fires.

The agent shell (robot_agent.node.agent.AgentNode) with its real firmware and codec; only the bus
is a
list (the handlers are what the loop would run, in the order the loop would run them).
"""

from __future__ import annotations

import time

from bus_schemas import Estop, Pose, Setpoint, Wheels, decode, encode, keys
from robot_agent.core.params import AgentConfig
from robot_agent.node.agent import AgentNode
from runtime import Received

FLEET = "backlog"


def _setpoint(t: float, seq: int) -> bytes:
    return encode(
        Setpoint(t=t, seq=seq, robot="r1", slot=1, role="follower", stage=1, parent=0,
                 x=0.45, y=0.0, theta=0.0, vx=0.0, vy=0.0)
    )  # fmt: skip


def _pose(t: float, seq: int) -> bytes:
    return encode(Pose(t=t, seq=seq, x=0.0, y=0.0, theta=0.0, robot="r1"))


def test_the_step_that_takes_a_backlogged_estop_and_every_later_one_publish_zero() -> None:
    out: list[tuple[float, Wheels]] = []

    def publish(key: str, payload: bytes, _qos: object) -> None:
        if key == keys.wheels_key(FLEET, "r1"):
            w = decode(payload, Wheels)
            assert isinstance(w, Wheels)
            out.append((time.monotonic(), w))

    node = AgentNode("r1", FLEET, AgentConfig(), publish)
    pose_key, sp_key = keys.pose_key(FLEET, "r1"), keys.setpoint_key(FLEET, "r1")
    seq = 0

    def rx(key: str, payload: bytes) -> Received:
        return Received(key, payload, time.monotonic())

    def fresh_inputs() -> None:
        nonlocal seq
        seq += 1
        now = time.monotonic()
        node.on_setpoint(rx(sp_key, _setpoint(now, seq)))
        node.on_pose(rx(pose_key, _pose(now, seq)))  # on-pose: steps

    for _ in range(20):
        fresh_inputs()
        time.sleep(0.005)
    assert out and out[-1][1].mode == "tracking" and out[-1][1].omega_r != 0.0

    # The backlog a starved loop finds: inputs received before the e-stop, the e-stop (received
    # now), then more inputs and timer ticks. Received times are all "now" (stamped on the
    # network thread while the loop did not run).
    before = len(out)
    fresh_inputs()  # received before the e-stop: tracking, legitimately
    estop = Estop(t=time.monotonic(), engage=True, robot=None)
    node.on_estop(rx(keys.estop_key(FLEET), encode(estop)))
    taken = len(out)
    assert taken == before + 2, "the e-stop steps at once (zero wheels now, not at the next tick)"
    first = out[before + 1][1]
    assert first.mode == "estop" and first.omega_r == 0.0 and first.omega_l == 0.0
    for i in range(30):
        fresh_inputs()
        node.control_timer(time.monotonic())
        if i % 5 == 0:
            node.publish_status()
        time.sleep(0.002)
    after = [w for _t, w in out[taken - 1 :]]
    assert len(after) > 30
    bad = [(w.seq, w.mode, w.omega_r) for w in after if w.omega_r or w.omega_l or w.mode != "estop"]
    assert not bad, bad
    # the newest wheels before the e-stop step are older than the e-stop's processing
    assert all(w.seq < first.seq for _t, w in out[: taken - 1])
