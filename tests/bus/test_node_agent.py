"""``formation agent`` as a real process on a real router: wheels from pose + setpoint, HOLD on
stale poses, estop latch, lockstep answers, clean exit, ``--config`` / ``--check-config``.

The test side is a Zenoh client session publishing the agent's inputs (bus inputs, not fake
processes). The helpers at the top (:class:`Recorder`, :class:`Feeder`, message builders) are
also used by the other node tests.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import pytest
import zenoh
from support.agent_io import FLEET, Feeder, nonzero, setpoint_msg, start_agent
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import REPO_ROOT, Spawner, child_env

import runtime as rt
from bus_schemas import Estop, Pose, PoseBatch, Status, Wheels, encode, keys, new_estop_id
from robot_agent.core.params import AgentConfig
from robot_agent.node.main import main as agent_main


def _ticked(msg, tick):  # type: ignore[no-untyped-def]
    """``msg`` encoded with its lockstep ``tick`` (a declared field of setpoint/slot/leader)."""
    return encode(replace(msg, tick=tick))


EXIT_BOUND_S = 1.5  # requirement: exit within 1 s of SIGTERM; 0.5 s margin for a loaded CI box

# ---------------------------------------------------------------------------------------------
# Fixtures
# ---------------------------------------------------------------------------------------------


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


@pytest.fixture
def pubs(client: zenoh.Session) -> Iterator[rt.Publishers]:
    p = rt.Publishers(client)
    yield p


# ---------------------------------------------------------------------------------------------
# Realtime
# ---------------------------------------------------------------------------------------------


def test_wheels_echo_pose_t_and_point_towards_the_setpoint(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, pubs: rt.Publishers
) -> None:
    child = start_agent(spawn, router)
    assert child.stdout().splitlines()[0] == "agent r1 ready"
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    target = {"xy": (0.45, 0.0)}  # 0.4 m straight ahead of the reference point (0.05, 0)
    with Feeder(pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=lambda: target["xy"]) as f:
        sent = f.sent_pose_t
        _, _, ahead = wheels.wait_for(lambda _r, _k, w: w.pose_t in sent and nonzero(w))
        # Straight ahead: both wheels forward at the same speed (eq 16: omega = 0).
        assert ahead.omega_r > 0.5 and ahead.omega_l > 0.5
        assert ahead.omega_r == pytest.approx(ahead.omega_l, rel=1e-6)
        assert ahead.pose_t in sent  # pose_t is the t of a pose this test published, exactly
        target["xy"] = (0.05, 0.4)  # to the left of the reference point: turn left
        t_switch = time.monotonic()
        _, _, left = wheels.wait_for(
            lambda r, _k, w: r > t_switch + 0.05 and w.pose_t in sent and nonzero(w)
        )
        assert left.omega_r > 0.0 > left.omega_l
        t_left = time.monotonic()
        _, _, st = status.wait_for(lambda r, _k, _s: r > t_left)
    assert st.mode == "tracking" and st.slot == 1 and st.role == "follower"
    assert st.robot == "r1" and st.rejected == 0 and st.pid == child.pid
    assert st.rx["pose"] > 0 and st.rx["setpoint"] > 0


def test_hold_with_zero_wheels_within_the_pose_bound_after_poses_stop(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, pubs: rt.Publishers
) -> None:
    """Poses stop: zero wheels (HOLD) within the default firmware's pose bound (the estimator's
    ``max_dropout_cmd_s`` from the last capture when it is on, ``stale_pose_s`` when off) plus
    100 ms (a tick, delivery), and the watchdog keeps publishing zero wheels."""
    start_agent(spawn, router)
    cfg = AgentConfig()
    bound = cfg.estimator.max_dropout_cmd_s if cfg.estimator.enabled else cfg.safety.stale_pose_s
    limit = bound + 0.1
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    with Feeder(pubs, "r1", pose=None, setpoint=lambda: (0.45, 0.0)):  # setpoints keep coming
        with Feeder(pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=None) as poses:
            wheels.wait_for(lambda _r, _k, w: nonzero(w))
            time.sleep(0.1)
        t_stop = poses.sent_pose_t[-1]
        time.sleep(limit + 0.3)
        items = wheels.snapshot()
        _, _, st = status.wait_for(lambda r, _k, _s: r > t_stop + limit)
    last_nonzero = max(r for r, _, w in items if nonzero(w))
    assert last_nonzero - t_stop < limit, f"non-zero wheels {last_nonzero - t_stop:.3f} s after"
    after = [w for r, _, w in items if r > t_stop + limit]
    assert len(after) >= 5, "the watchdog timer keeps publishing (zero) wheels"
    assert all(not nonzero(w) for w in after)
    assert st.mode == "hold"


def test_estop_zeroes_the_wheels_within_100_ms_and_latches_until_release(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, pubs: rt.Publishers
) -> None:
    start_agent(spawn, router)
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    estop_key = keys.estop_key(FLEET)

    def estop(engage: bool, robot: str | None) -> float:
        t = time.monotonic()
        eid = new_estop_id() if engage else None
        msg = Estop(t=t, engage=engage, robot=robot, id=eid)
        pubs.put(estop_key, encode(msg), rt.QOS_CRITICAL)
        return t

    with Feeder(pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=lambda: (0.45, 0.0)):
        wheels.wait_for(lambda _r, _k, w: nonzero(w))
        t_engage = estop(True, None)  # the whole fleet
        r_zero, _, _ = wheels.wait_for(lambda r, _k, w: r > t_engage and not nonzero(w))
        assert r_zero - t_engage < 0.1
        estop(False, "r2")  # another robot's release: ignored
        time.sleep(0.3)
        latched = [w for r, _, w in wheels.snapshot() if r > r_zero]
        assert len(latched) >= 10 and all(not nonzero(w) for w in latched)
        _, _, st = status.wait_for(lambda r, _k, _s: r > r_zero)
        assert st.mode == "estop"
        # scopes (issue 13 item 4): r1's own release does not clear the fleet's e-stop ...
        t_release = estop(False, "r1")
        time.sleep(0.3)
        assert all(not nonzero(w) for r, _, w in wheels.snapshot() if r > t_release)
        t_release = estop(False, None)  # ... the fleet's release does
        wheels.wait_for(lambda r, _k, w: r > t_release and nonzero(w), timeout_s=1.0)
        t_engage = estop(True, "r1")  # own id
        wheels.wait_for(lambda r, _k, w: r > t_engage and not nonzero(w), timeout_s=0.1)
        estop(True, None)
        t_release = estop(False, None)  # the fleet's release does not clear r1's own e-stop
        time.sleep(0.3)
        assert all(not nonzero(w) for r, _, w in wheels.snapshot() if r > t_release)
        _, _, st = status.wait_for(lambda r, _k, _s: r > t_release + 0.25)
        assert st.mode == "estop"
        t_release = estop(False, "r1")
        wheels.wait_for(lambda r, _k, w: r > t_release and nonzero(w), timeout_s=1.0)


def test_fixed_loop_steps_at_the_timer_rate_not_at_the_pose_rate(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, pubs: rt.Publishers
) -> None:
    start_agent(spawn, router, "--loop", "fixed", "--rate-hz", "20")
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    with Feeder(
        pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=lambda: (0.45, 0.0), period_s=0.01
    ) as f:
        first, _, _ = wheels.wait_for(lambda _r, _k, w: nonzero(w))
        time.sleep(0.5)
        window = [w for r, _, w in wheels.snapshot() if first <= r < first + 0.5]
        n_poses = len([t for t in f.sent_pose_t if first <= t < first + 0.5])
    assert 6 <= len(window) <= 14, f"{len(window)} wheels messages in 0.5 s at --rate-hz 20"
    assert n_poses > 2 * len(window)  # stepping on poses would have given one per pose


def test_sigterm_exits_0_within_a_second(spawn: Spawner, router: RouterHandle) -> None:
    child = start_agent(spawn, router)
    time.sleep(0.2)
    elapsed = child.stop(signal.SIGTERM)
    assert child.proc.returncode == 0, child.describe()
    assert elapsed < EXIT_BOUND_S, f"exit took {elapsed:.3f} s"


# ---------------------------------------------------------------------------------------------
# Lockstep
# ---------------------------------------------------------------------------------------------


def test_lockstep_steps_on_the_clock_with_the_setpoint_of_the_previous_tick(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, pubs: rt.Publishers
) -> None:
    from bus_schemas import Clock

    start_agent(spawn, router, "--lockstep")
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    clock_key = keys.clock_key(FLEET)
    dt = 0.02

    def clock(k: int) -> None:
        pubs.put(clock_key, encode(Clock(t=k * dt, seq=k + 1, tick=k)), rt.QOS_CRITICAL)

    def setpoint(tick: int, x: float, y: float) -> None:
        msg = setpoint_msg("r1", x, y, t=tick * dt, seq=tick + 1)
        pubs.put(keys.setpoint_key(FLEET, "r1"), _ticked(msg, tick), rt.QOS_CRITICAL)

    # Warm up with clocks 0, 1, ... until the answer to clock k shows that clock's frame arrived
    # before it (the test session knows the agent's subscriptions by then); K: next free tick.
    # The answer to tick k itself: an earlier one (tick 0's pose_t equals its t too) says
    # nothing of frame k, and on a loaded machine it may be the one that has just come in.
    deadline = time.monotonic() + 10.0
    k = 0
    while True:
        if k > 0:
            setpoint(k - 1, 0.45, 0.0)  # the firmware reads the pose only with a setpoint
        # (a lockstep agent takes its own pose from the plant's frame)
        frame = PoseBatch(
            t=k * dt, seq=k + 1, robots=("r1",), x=(0.0,), y=(0.0,), theta=(0.0,), stamp=k * dt
        )
        pubs.put(keys.poses_key(FLEET), encode(frame), rt.QOS_CRITICAL)
        clock(k)
        try:
            _, _, w = wheels.wait_for(lambda _r, _k, w, k=k: w.tick == k, timeout_s=0.5)
        except AssertionError:  # not answered yet: the next clock
            w = None
        if isinstance(w, Wheels) and w.pose_t == k * dt:
            break
        assert time.monotonic() < deadline, "no answer to a clock"
        k += 1
    K = k + 1
    pose_t = k * dt
    time.sleep(0.1)
    no_timer = len(wheels.snapshot())
    time.sleep(0.1)
    assert len(wheels.snapshot()) == no_timer, "in lockstep wheels answer clocks only"

    def answer(k: int) -> Wheels:
        _, _, w = wheels.wait_for(lambda _r, _k, w: w.tick == k, timeout_s=2.0)
        assert isinstance(w, Wheels)
        return w

    setpoint(K - 1, 0.45, 0.0)  # ahead
    clock(K)
    w1 = answer(K)
    assert w1.t == K * dt and w1.pose_t == pose_t
    assert w1.omega_r > 0.5 and w1.omega_r == pytest.approx(w1.omega_l)
    setpoint(K, 0.05, 0.4)  # left, for clock K+1
    setpoint(K + 1, 0.05, -0.4)  # right, for clock K+2 (already here when K+1 is handled)
    clock(K + 1)
    w2 = answer(K + 1)
    assert w2.omega_r > 0.0 > w2.omega_l, "clock K+1 uses the setpoint of tick K"
    wheels.clear()
    clock(K + 1)  # re-announced: the same answer again, not a second step
    again = answer(K + 1)
    assert again == w2
    clock(K + 2)
    w3 = answer(K + 2)
    assert w3.omega_l > 0.0 > w3.omega_r
    clock(K + 5)  # nothing computed on tick K+4 for this robot: no setpoint, zero wheels
    w5 = answer(K + 5)
    assert not nonzero(w5) and w5.pose_t == pose_t

    # The tick thread reads the setpoints waiting before a clock, so the coordinator's repeats
    # of tick K+6 (it answers a re-announced clock again) may come before clock K+6 is
    # handled: they must not push out tick K+5's, the one clock K+6 steps on.
    def pose_at(k: int) -> None:
        pose = Pose(t=k * dt, seq=k + 1, x=0.0, y=0.0, theta=0.0, robot="r1")
        pubs.put(keys.pose_key(FLEET, "r1"), encode(pose), rt.QOS_CRITICAL)

    setpoint(K + 5, 0.45, 0.0)  # ahead
    for _ in range(3):
        setpoint(K + 6, 0.05, 0.4)  # left, three times
    pose_at(K + 6)
    clock(K + 6)
    w6 = answer(K + 6)
    # ahead: both wheels forward (tick K+6's, to the left, would turn: omega_l < 0 < omega_r)
    assert w6.omega_r > 0.5 and w6.omega_l > 0.5, "tick K+5's setpoint"

    # An e-stop is handled on the event loop while the tick thread steps (under the agent's
    # guard): the next clock's answer is zero wheels in mode estop, until the release.
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    estop = Estop(t=time.monotonic(), engage=True, robot=None, id=new_estop_id())
    pubs.put(keys.estop_key(FLEET), encode(estop), rt.QOS_CRITICAL)
    status.wait_for(lambda _r, _k, st: st.mode == "estop", timeout_s=3.0)
    setpoint(K + 7, 0.45, 0.0)
    pose_at(K + 7)
    clock(K + 7)
    w7 = answer(K + 7)
    assert not nonzero(w7) and w7.mode == "estop"
    release = Estop(t=time.monotonic(), engage=False, robot=None, id=None)
    pubs.put(keys.estop_key(FLEET), encode(release), rt.QOS_CRITICAL)
    status.wait_for(lambda _r, _k, st: st.mode != "estop", timeout_s=3.0)
    setpoint(K + 8, 0.45, 0.0)
    pose_at(K + 8)
    clock(K + 8)
    w8 = answer(K + 8)
    assert w8.mode != "estop" and w8.omega_r > 0.5 and w8.omega_l > 0.5, "released: it moves"


# ---------------------------------------------------------------------------------------------
# Robot config
# ---------------------------------------------------------------------------------------------

EXAMPLE = REPO_ROOT / "deploy" / "config" / "r1.example.toml"


def test_check_config_reports_ok_or_every_problem(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Through the real command once; the template names the robot's TLS config under /etc,
    # absent on a development machine.
    as_shipped = subprocess.run(
        [sys.executable, "-m", "formation", "agent", "--check-config", str(EXAMPLE)],
        cwd=REPO_ROOT,
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert as_shipped.returncode == 1
    assert as_shipped.stdout.strip().startswith("zenoh.config_file:")

    local = tmp_path / "r1.toml"
    zenoh_file = REPO_ROOT / "deploy" / "zenoh" / "robot-mtls.json5"
    text = EXAMPLE.read_text().replace("/etc/formation/zenoh/robot-mtls.json5", str(zenoh_file))
    local.write_text(text)
    assert agent_main(["--check-config", str(local)]) == 0
    assert capsys.readouterr().out.strip() == "OK"

    broken = tmp_path / "broken.toml"
    broken.write_text("x = 1\n" + text.replace("wheel_radius_m = 0.03", 'wheel_radius_m = "big"'))
    assert agent_main(["--check-config", str(broken)]) == 1
    problems = capsys.readouterr().out.strip().splitlines()
    assert any(p.startswith("geometry.wheel_radius_m") for p in problems), problems
    assert any(p.startswith("x:") for p in problems), problems


def test_config_file_gives_id_fleet_and_endpoint(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, tmp_path: Path
) -> None:
    cfg = tmp_path / "r7.toml"
    cfg.write_text(
        'robot_id = "r7"\nfleet = "lab"\n[safety]\nstale_pose_s = 0.3\n'
        f'[zenoh]\nmode = "client"\nendpoints = ["{router.endpoint}"]\n'
        '[motor]\nbackend = "bus"\n'
    )
    status = Recorder(client, keys.status_key("lab", "r7"), decoder_of(Status))
    child = spawn("agent", "--config", str(cfg), ready="agent r7 ready")
    _, key, st = status.wait_for(lambda *_: True)
    assert key == "formation/lab/robot/r7/status" and st.robot == "r7" and st.mode == "idle"
    assert child.stop() < EXIT_BOUND_S and child.proc.returncode == 0


def test_bad_arguments_exit_2_before_connecting(capsys: pytest.CaptureFixture[str]) -> None:
    assert agent_main(["--endpoint", "tcp/127.0.0.1:9"]) == 2
    assert "--id is required" in capsys.readouterr().err
    assert agent_main(["--id", "R 1"]) == 2
    assert "invalid robot id" in capsys.readouterr().err
    assert agent_main(["--id", "r9", "--scenario", "paper-exp2"]) == 2
    out = capsys.readouterr()
    assert "not in scenario" in out.err and out.out == ""


def test_roboclaw_backend_from_the_config_drives_the_motors(
    spawn: Spawner, router: RouterHandle, pubs: rt.Publishers, tmp_path: Path
) -> None:
    from support.roboclaw_emulator import RoboClawEmulator

    with RoboClawEmulator() as emu:
        cfg = tmp_path / "r1.toml"
        cfg.write_text(
            f'robot_id = "r1"\n[zenoh]\nmode = "client"\nendpoints = ["{router.endpoint}"]\n'
            f'[motor]\nbackend = "roboclaw"\nport = "{emu.port}"\nmode = "duty"\n'
        )
        child = spawn("agent", "--config", str(cfg), ready="agent r1 ready")
        with Feeder(pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=lambda: (0.45, 0.0)):
            # Straight ahead: both motors forward (M1 = right wheel by default), same duty.
            assert emu.wait_for(lambda: min(emu.speeds()) > 0, timeout_s=5.0), emu.speeds()
            m1, m2 = emu.speeds()
            assert m1 == m2
        # Poses stop: HOLD, the firmware's zero command becomes a stop of both motors.
        assert emu.wait_for(lambda: emu.speeds() == (0, 0), timeout_s=1.0)
        assert child.stop() < EXIT_BOUND_S and child.proc.returncode == 0
        assert emu.serial_timeout_tenths == 5  # the controller's own timeout was armed
