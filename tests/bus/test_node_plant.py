"""``formation plant`` as a real process on a real router: camera-rate poses, wheel commands,
dead robots, drag, and the lockstep handshake (clock k advances only on every answer).

The test session plays the agents and the coordinator: liveliness tokens, ``wheels`` and (in
lockstep) ``leader`` messages published from the test (bus inputs, not fake processes).
"""

from __future__ import annotations

import signal
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import replace

import msgpack
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.lockstep_equality import FLEET, SCENARIO, lockstep_equals_simulate
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import (
    Clock,
    Disturbance,
    Leader,
    Pose,
    PoseBatch,
    Truth,
    TruthBatch,
    Wheels,
    encode,
    keys,
)
from scenario import Disturbance as ScheduledDisturbance


def _ticked(msg, tick):  # type: ignore[no-untyped-def]
    """``msg`` encoded with its lockstep ``tick`` (a declared field of setpoint/slot/leader)."""
    return encode(replace(msg, tick=tick))


STATUS_KEY = f"formation/{FLEET}/plant/status"


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


def wheels_msg(omega: float, *, t: float, seq: int, tick: int | None = None) -> bytes:
    return encode(
        Wheels(
            t=t,
            seq=seq,
            omega_r=omega,
            omega_l=omega,
            power_r=omega / 10.0,
            power_l=omega / 10.0,
            pose_t=None,
            tick=tick,
        )
    )


def latest_truth(rec: Recorder, robot: str) -> Truth:
    items = [m for _, k, m in rec.snapshot() if k.endswith(f"/{robot}/truth")]
    assert items, f"no truth of {robot}"
    last: Truth = items[-1]
    return last


class WheelsFeeder:
    """Publishes ``wheels`` (both wheels at ``omega`` rad/s) for ``robot`` at 50 Hz."""

    def __init__(self, pubs: rt.Publishers, robot: str, omega: float) -> None:
        self.pubs, self.robot, self.omega = pubs, robot, omega
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        seq = 0
        while not self._stop.is_set():
            seq += 1
            payload = wheels_msg(self.omega, t=time.monotonic(), seq=seq)
            self.pubs.put(keys.wheels_key(FLEET, self.robot), payload, rt.QOS_CRITICAL)
            self._stop.wait(0.02)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


def test_realtime_poses_wheels_dead_robot_and_drag(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    poses = Recorder(client, keys.all_poses_pattern(FLEET), decoder_of(Pose))
    batches = Recorder(client, keys.poses_key(FLEET), decoder_of(PoseBatch))
    truth = Recorder(client, keys.all_truth_pattern(FLEET), decoder_of(Truth))
    status = Recorder(client, STATUS_KEY, msgpack.unpackb)
    child = spawn("plant", "--scenario", "paper-exp2", "--endpoint", router.endpoint, ready="plant")
    assert child.stdout().splitlines()[0] == "plant ready"

    # Camera: ~30 frames/s per robot, delivered ~30 ms (the scenario's latency) after capture.
    first, _, _ = poses.wait_for(lambda *_: True)
    time.sleep(0.6)
    window = [(r, k, m) for r, k, m in poses.snapshot() if first + 0.05 <= r < first + 0.55]
    for rid in SCENARIO.robot_ids:
        n = sum(1 for _, k, m in window if k.endswith(f"/{rid}/pose") and m.robot == rid)
        assert 12 <= n <= 18, f"{n} poses of {rid} in 0.5 s"
    delays = [r - m.t for r, _, m in window]
    assert 0.025 <= statistics.median(delays) <= 0.06
    _, _, batch = batches.wait_for(lambda *_: True)
    assert batch.robots == SCENARIO.robot_ids and len(batch.x) == 3

    # Wheels (no agent token needed) go through the link and move r1 forward (+x, theta ~ 0.05).
    x0_r1, x0_r2 = latest_truth(truth, "r1").x, latest_truth(truth, "r2").x
    feeder = WheelsFeeder(pubs, "r1", 5.0)  # v = R omega = 0.15 m/s
    time.sleep(0.5)
    x1 = latest_truth(truth, "r1").x
    assert 0.03 < x1 - x0_r1 < 0.1
    assert latest_truth(truth, "r2").x == x0_r2  # zero command: exactly still

    # With a token, r1's agent is alive; the last command keeps acting when wheels stop ...
    token = rt.declare_token(client, keys.alive_robot_key(FLEET, "r1"))
    status.wait_for(lambda _r, _k, s: s["alive"] == ["r1"])
    feeder.stop()
    x2 = latest_truth(truth, "r1").x
    time.sleep(0.2)
    x3 = latest_truth(truth, "r1").x
    assert x3 - x2 > 0.015
    # ... and its motors stop when the token disappears.
    token.undeclare()
    status.wait_for(lambda _r, _k, s: s["alive"] == [])
    time.sleep(0.3)  # the wheels spin down with the motor lag (tau = 0.05 s)
    x4 = latest_truth(truth, "r1").x
    time.sleep(0.2)
    assert abs(latest_truth(truth, "r1").x - x4) < 5e-4  # was 0.015 per 0.2 s when alive

    # Drag r2 back 0.3 m over 0.2 s.
    drag = Disturbance(t=time.monotonic(), robot="r2", kind="drag", dx=-0.3, dy=0.0, duration_s=0.2)
    pubs.put(keys.disturbance_key(FLEET), encode(drag), rt.QOS_CRITICAL)
    time.sleep(0.4)
    assert latest_truth(truth, "r2").x == pytest.approx(x0_r2 - 0.3, abs=1e-9)
    t_check = time.monotonic()
    _, _, st = status.wait_for(lambda r, _k, _s: r > t_check)
    assert st["rejected"] == 0 and st["state"] == "running" and st["mode"] == "realtime"
    assert st["rx"]["disturbance"] == 1 and st["link_sent"] > 0


def test_lockstep_waits_for_the_fleet_and_advances_only_on_every_answer(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, "r2"))]
    clocks = Recorder(client, keys.clock_key(FLEET), decoder_of(Clock))
    truths = Recorder(client, keys.truths_key(FLEET), decoder_of(TruthBatch))
    frames = Recorder(client, keys.poses_key(FLEET), decoder_of(PoseBatch))
    # a lockstep plant puts truth and frames as batches, and a robot's own `truth` and `pose`
    # only while someone subscribes to them: r1's truth from the start, r2's from tick 5
    r1_truth = Recorder(client, keys.truth_key(FLEET, "r1"), decoder_of(Truth))
    status = Recorder(client, STATUS_KEY, msgpack.unpackb)
    dt = SCENARIO.dt_s
    child = spawn(
        "plant",
        "--scenario",
        "paper-exp2",
        "--lockstep",
        "--wait-robots",
        "--lockstep-timeout",
        "0.5",
        "--duration",
        "0.3",  # ticks 0..15
        "--endpoint",
        router.endpoint,
        ready="plant ready",
    )

    def answer(k: int, robots: tuple[str, ...], leader: bool = True) -> float:
        for rid in robots:
            omega = 5.0 if rid == "r1" else 0.0
            payload = wheels_msg(omega, t=k * dt, seq=k + 1, tick=k)
            pubs.put(keys.wheels_key(FLEET, rid), payload, rt.QOS_CRITICAL)
        if leader:
            msg = Leader(t=k * dt, seq=k + 1, x=0.0, y=0.0, theta=0.0, v_mps=0.0, omega_radps=0.0)
            pubs.put(keys.leader_key(FLEET), _ticked(msg, k), rt.QOS_CRITICAL)
        return time.monotonic()

    def clock(k: int, timeout_s: float = 2.0) -> float:
        r, _, c = clocks.wait_for(lambda _r, _k, c: c.tick == k, timeout_s)
        assert c.t == k * dt
        return r

    # --wait-robots: no clock until every robot's and a coordinator's token are there.
    deadline = time.monotonic() + 5.0
    while "waiting for r1, r3, a coordinator" not in child.stderr():
        assert time.monotonic() < deadline, child.describe()
        time.sleep(0.02)
    time.sleep(0.2)
    assert clocks.snapshot() == []
    tokens += [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in ("r1", "r3")]
    tokens.append(rt.declare_token(client, keys.alive_coordinator_key(FLEET, "test")))

    clock(0)
    answer(0, ("r1", "r2"))  # r3 missing
    time.sleep(0.3)
    assert max(c.tick for _, _, c in clocks.snapshot()) == 0
    sent = answer(0, ("r3",), leader=False)
    assert clock(1) - sent < 0.2
    t_wait = time.monotonic()  # nobody answers tick 1: the plant goes on after 0.5 s
    elapsed = clock(2, timeout_s=3.0) - t_wait
    assert 0.45 <= elapsed <= 1.3
    r2_truth: Recorder | None = None
    for k in range(2, 16):
        answer(k, ("r1", "r2", "r3"))
        if k < 15:
            clock(k + 1)
        if k == 5:
            r2_truth = Recorder(client, keys.truth_key(FLEET, "r2"), decoder_of(Truth))
    child.proc.wait(timeout=5.0)
    assert child.proc.returncode == 0, child.describe()
    _, _, done = status.wait_for(lambda _r, _k, s: s["state"] == "done")
    assert done["timeouts"] == 1 and done["tick"] == 15 and done["rejected"] == 0
    x0 = SCENARIO.initial
    batches = [m for _, _, m in truths.snapshot()]
    assert [b.stamp for b in batches] == [k * dt for k in range(16)]  # truth at every tick
    end = batches[-1]
    last = {rid: (x, y) for rid, x, y in zip(end.robots, end.x, end.y, strict=True)}
    assert last["r1"][0] > x0[0][0] + 0.01  # r1 drove
    assert last["r2"] == (x0[1][0], x0[1][1])  # r2's wheels stayed at zero
    assert frames.snapshot() and all(
        set(m.robots) == {"r1", "r2", "r3"} for _, _, m in frames.snapshot()
    )
    # r1's own truth, subscribed from the start: every tick, the batch's values
    keyed = [(m.t, m.x, m.y, m.theta) for _, _, m in r1_truth.snapshot()]
    i = end.robots.index("r1")
    assert keyed == [(b.stamp, b.x[i], b.y[i], b.theta[i]) for b in batches]
    # r2's, subscribed at tick 6: its first message is its key's first (nothing put before)
    assert r2_truth is not None
    late = [m for _, _, m in r2_truth.snapshot()]
    assert late and late[0].seq == 1 and late[0].t > 5 * dt
    del tokens


def test_the_three_shells_reproduce_the_in_process_simulator_bit_for_bit() -> None:
    """The lockstep protocol over the shells equals ``formation.sim.simulate.run`` exactly. (The
    same holds over a real router: ``formation up --lockstep``.) The clocks relay which robots
    were TRACKING on the previous tick (the safety filter's cooperative neighbours)."""
    # The scenario's drag comes at 30 s; one at 0.3 s exercises the scheduled disturbances.
    drag = ScheduledDisturbance(t_s=0.3, robot="r1", kind="drag", dx=-0.2, duration_s=0.5)
    scenario = SCENARIO.with_overrides(disturbances=(drag,))
    got = lockstep_equals_simulate(scenario, 1.0)
    relayed = [c.tracking for c in got["clocks"]]
    assert relayed[0] == ()  # nobody answered a tick before clock 0
    assert any(set(r or ()) == set(got["ids"]) for r in relayed)  # everyone tracking later


def test_lockstep_equals_the_simulator_with_the_estimator_and_camera_latency() -> None:
    """With the estimator on, 60 ms of camera latency and a camera loss, the shells still equal
    the in-process simulator bit for bit: pose capture times (the estimator's input) and the
    pose uncertainty handed to the safety filter follow one rule in both runtimes."""
    from robot_agent.core.params import EstimatorParams

    agent = replace(SCENARIO.agent, estimator=replace(EstimatorParams(), enabled=True))
    loss = ScheduledDisturbance(t_s=0.4, robot="r2", kind="camera_loss", duration_s=0.3)
    drag = ScheduledDisturbance(t_s=0.2, robot="r1", kind="drag", dx=-0.15, duration_s=0.4)
    scenario = SCENARIO.with_overrides(
        agent=agent,
        camera=replace(SCENARIO.camera, latency_s=0.06),
        disturbances=(drag, loss),
    )
    got = lockstep_equals_simulate(scenario, 1.2)
    status = got["result"].firmware_status
    assert all(s["mode"] == "tracking" for s in status.values()), status  # rode through


def test_lockstep_agent_host_equals_the_simulator_bit_for_bit() -> None:
    """The same with one agent host running every robot (batched poses, setpoints, wheels)."""
    drag = ScheduledDisturbance(t_s=0.3, robot="r1", kind="drag", dx=-0.2, duration_s=0.5)
    lockstep_equals_simulate(SCENARIO.with_overrides(disturbances=(drag,)), 1.0, hosts=True)


def test_lockstep_equals_the_simulator_with_scripted_operator_commands() -> None:
    """Scripted operator commands (``[[operator]]``: a reshape that adds the spare's slot, a
    teleop stream that stops and trips the deadman, a goal) are played by the in-process
    simulator and by the lockstep coordinator at the same ticks: the shells still equal the
    simulator bit for bit, and the commands did what they say."""
    import tomllib

    from scenario.load import parse, resolve
    from scenario.resize import scenario_with_robots

    data = scenario_with_robots(tomllib.loads(resolve("paper-exp2").read_text()), 3, spares=1)
    data["operator"] = [
        {"t_s": 0.2, "command": "shape", "kind": "chevron", "slots": 4},
        {"t_s": 0.6, "command": "teleop", "v_mps": 0.05, "omega_radps": 0.2, "duration_s": 0.5},
        {"t_s": 1.8, "command": "goal", "x": 0.5, "y": 0.5},
    ]
    scenario = parse(data)
    got = lockstep_equals_simulate(scenario, 2.4)
    res = got["result"]
    applied = res.log.meta["operator"]["applied"]
    assert [a["command"] for a in applied] == ["shape", "goal"]
    assert all(a["refused"] is None for a in applied) and not res.log.meta["operator"]["rejects"]
    # the spare took the slot the reshape added, from the tick after the command
    k_shape = round(0.2 / scenario.dt_s) + 1
    assert 3 in res.log.slot_ids and (res.log.slot_of[k_shape:, 3] == 3).all()
    assert (res.log.slot_of[: k_shape - 1, 3] == -1).all()
    # the teleop turned the leader off its scripted straight line (heading 0 there)
    k_teleop = round(0.6 / scenario.dt_s)
    assert res.log.leader[k_teleop - 1, 2] == 0.0 and res.log.leader[-1, 2] > 0.1


def test_lockstep_equals_the_simulator_when_a_scripted_reshape_drops_a_robot() -> None:
    """A column of three told to be a column of two: the rearmost slot is dropped at the end of
    the transition and its robot, without a setpoint, holds; lockstep still equals the
    in-process simulator bit for bit."""
    import math
    import tomllib

    from scenario.load import parse, resolve

    data = tomllib.loads(resolve("paper-exp2").read_text())
    column = [{"slot": 0}] + [
        {"slot": k, "parent": k - 1, "b_m": 0.4, "phi_rad": math.pi / 2} for k in (1, 2)
    ]
    data["formation"] = {"kind": "explicit", "slots": column}
    data["operator"] = [{"t_s": 0.1, "command": "shape", "kind": "column", "slots": 2}]
    scenario = parse(data)
    got = lockstep_equals_simulate(scenario, 3.4)
    res = got["result"]
    (done,) = res.log.reshapes
    assert done["slots"] == 2 and done["end_s"] <= 3.2  # the dropped slot had nowhere to go
    ids = list(res.log.robot_ids)
    (rear,) = [r for j, r in enumerate(ids) if res.log.slot_of[20, j] == 2]
    last = dict(zip(ids, res.log.slot_of[-1].tolist(), strict=True))
    assert last[rear] == -1 and sorted(last.values()) == [-1, 0, 1]  # the rearmost left
    assert res.firmware_status[rear]["mode"] == "hold"  # no setpoint: it holds where it is


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_lockstep_plant_waiting_on_its_tick_thread_exits_within_a_second_of_a_signal(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, sig: int
) -> None:
    """The lockstep loop is a thread of its own (PlantNode.run_lockstep_blocking), asleep
    until the tick's last answer: a signal still ends the process within a second, mid-wait,
    with exit status 0; the answers that did come were handled on Zenoh's thread (its
    status counts them) and the tick thread went on only with all of them."""
    pubs = rt.Publishers(client)
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in ("r1", "r2", "r3")]
    tokens.append(rt.declare_token(client, keys.alive_coordinator_key(FLEET, "test")))
    clocks = Recorder(client, keys.clock_key(FLEET), decoder_of(Clock))
    status = Recorder(client, STATUS_KEY, msgpack.unpackb)
    child = spawn(
        "plant", "--scenario", "paper-exp2", "--lockstep", "--wait-robots",
        "--lockstep-timeout", "60", "--endpoint", router.endpoint, ready="plant ready",
    )  # fmt: skip
    clocks.wait_for(lambda _r, _k, c: c.tick == 0, 5.0)
    for rid in ("r1", "r2"):  # r3 and the leader never answer tick 0: the plant waits
        wheels = wheels_msg(1.0, t=0.0, seq=1, tick=0)
        pubs.put(keys.wheels_key(FLEET, rid), wheels, rt.QOS_CRITICAL)
    _, _, seen = status.wait_for(lambda _r, _k, s: s["rx"]["wheels"] == 2, 3.0)
    assert seen["tick"] == 0 and seen["state"] == "running"
    assert max(c.tick for _, _, c in clocks.snapshot()) == 0
    took = child.stop(sig)
    assert took < 1.0, child.describe()
    assert child.proc.returncode == 0, child.describe()
    del tokens
