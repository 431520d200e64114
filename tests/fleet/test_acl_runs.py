"""Authenticated runs as processes (formation up --secure, lockstep and realtime) and the
`formation certs` command: every process gets its identity and the run reaches its end."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from support.bus_inbox import Inbox
from support.spawn import free_port

from bus_schemas import acl, keys
from bus_schemas.acl import Identity, Kind

REPO = Path(__file__).resolve().parents[2]
FLEET = "demo"


# ---------------------------------------------------------------------- a local run, processes


@pytest.mark.zenoh
@pytest.mark.slow
def test_authenticated_local_run_processes(tmp_path: Path, spawn) -> None:  # type: ignore[no-untyped-def]
    """What a launcher does (formation.launch.pki.write_run_configs): a ``formation router`` and a
    ``formation agent`` with the generated configs. The agent runs authenticated (its status
    arrives, it tracks the coordinator's setpoint from the localization's poses), and setpoints
    that robot r2's certificate forges for r1 never reach it (its own receive counter)."""
    import zenoh
    from support.agent_io import setpoint_msg

    from bus_schemas import Pose, Status, decode, encode
    from formation.launch.pki import write_run_configs
    from formation.launch.router import READY_PREFIX

    idents = [
        acl.robot("r1"),
        acl.robot("r2"),
        acl.coordinator("main"),
        Identity(Kind.LOCALIZATION),
        Identity(Kind.OBSERVER),
    ]
    rc = write_run_configs(tmp_path / "run", idents, port=free_port())
    spawn("router", "--zenoh-config", str(rc.router), ready=READY_PREFIX)
    spawn("agent", "--id", "r1", "--zenoh-config", str(rc.clients["robot.r1"]), ready="agent")

    def open_as(cn: str) -> zenoh.Session:
        return zenoh.open(zenoh.Config.from_file(str(rc.clients[cn])))

    sessions = [open_as(cn) for cn in ("observer", "coordinator.main", "localization", "robot.r2")]
    observer, coord, loc, r2 = sessions
    try:
        statuses: list[Status] = []
        lock = threading.Lock()
        fence = Inbox()

        def on_status(sample) -> None:  # type: ignore[no-untyped-def]
            msg = decode(sample.payload.to_bytes(), Status)
            assert isinstance(msg, Status), msg
            with lock:
                statuses.append(msg)

        subs = [
            observer.declare_subscriber(_key("robot/r1/status"), on_status),
            observer.declare_subscriber(_key("robot/r2/status"), fence),
        ]

        def latest(pred, timeout_s: float = 10.0) -> Status:  # type: ignore[no-untyped-def]
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                with lock:
                    for st in reversed(statuses):
                        if pred(st):
                            return st
                time.sleep(0.02)
            raise AssertionError(f"no such status; last {statuses[-1:] if statuses else None}")

        first = latest(lambda s: True)
        assert first.robot == "r1"
        # tracking: the coordinator's setpoint and the localization's poses are read
        t0 = time.monotonic()
        seq = 0
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            seq += 1
            now = time.monotonic()
            loc.put(_key("robot/r1/pose"), encode(Pose(t=now, seq=seq, x=0.0, y=0.0, theta=0.0)))
            coord.put(
                _key("robot/r1/setpoint"), encode(setpoint_msg("r1", 0.3, 0.0, t=now, seq=seq))
            )
            with lock:
                if statuses and statuses[-1].mode == "tracking":
                    break
            time.sleep(0.02)
        tracking = latest(lambda s: s.mode == "tracking", timeout_s=1.0)
        assert time.monotonic() - t0 < 10.0
        # forged setpoints from r2's certificate: dropped at the router, never counted by r1
        rx_before = latest(lambda s: s.rx is not None and s.seq > tracking.seq).rx
        assert rx_before is not None
        for k in range(20):
            r2.put(_key("robot/r1/setpoint"), encode(setpoint_msg("r1", 5.0, 5.0, t=1.0, seq=k)))
        r2.put(_key("robot/r2/status"), b"fence")  # allowed: arrives after the forged ones
        assert fence.wait(_key("robot/r2/status"), b"fence")
        now = time.monotonic()
        coord.put(_key("robot/r1/setpoint"), encode(setpoint_msg("r1", 0.3, 0.0, t=now, seq=10**6)))
        want = rx_before.get("setpoint", 0) + 1
        after = latest(lambda s: s.rx is not None and s.rx.get("setpoint", 0) >= want)
        assert after.rx is not None and after.rx["setpoint"] == want, (rx_before, after.rx)
        for sub in subs:
            sub.undeclare()
    finally:
        for s in sessions:
            s.close()


# ---------------------------------------------------------------------- certificates


def test_formation_certs_cli(tmp_path: Path) -> None:
    """Deployment certificates: CN = identity, private keys 0600, the CA kept on a re-run (so a
    robot added later is signed by the same CA), bad names refused before anything is written."""
    import stat

    from cryptography import x509
    from cryptography.x509.oid import NameOID

    from formation.launch.pki import main as certs_main

    out = tmp_path / "fleet"
    assert certs_main(["-o", str(out), "--robots", "Robot 1"]) == 2
    assert not out.exists()
    assert certs_main(["-o", str(out), "--robots", "r1", "--router-host", "coord.lan"]) == 0
    ca_before = (out / "ca" / "ca.pem").read_bytes()
    assert certs_main(["-o", str(out), "--robots", "r2"]) == 0
    assert (out / "ca" / "ca.pem").read_bytes() == ca_before
    expected = {"robot.r1", "robot.r2", "coordinator.main", "coordinator.standby"}
    expected |= {"localization", "operator", "observer", "ros2"}
    for cn in expected:
        cert = x509.load_pem_x509_certificate((out / cn / "cert.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == cn
        assert stat.S_IMODE((out / cn / "key.pem").stat().st_mode) == 0o600
        assert (out / cn / "ca.pem").read_bytes() == ca_before
    router = x509.load_pem_x509_certificate((out / "router" / "cert.pem").read_bytes())
    san = router.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.DNSName) == ["coord.lan"]


@pytest.mark.zenoh
@pytest.mark.slow
def test_secure_lockstep_fleet_runs_to_the_end(tmp_path: Path, spawn) -> None:  # type: ignore[no-untyped-def]
    """Every key each process needs is allowed: router, plant, two coordinators and three
    agents, each with its own certificate and the generated access control, run a lockstep
    scenario to its end (every tick answered, every robot tracking, the plant exits 0)."""
    import zenoh

    from bus_schemas import Status, decode
    from formation.launch.pki import write_run_configs
    from formation.launch.router import READY_PREFIX

    robots = ("r1", "r2", "r3")
    idents = [acl.robot(r) for r in robots]
    idents += [acl.coordinator("main"), acl.coordinator("standby"), Identity(Kind.PLANT)]
    idents.append(Identity(Kind.OBSERVER))
    rc = write_run_configs(tmp_path / "run", idents, port=free_port())

    def conf(cn: str) -> list[str]:
        return ["--zenoh-config", str(rc.clients[cn]), "--lease-ms", "700"]

    spawn("router", "--zenoh-config", str(rc.router), ready=READY_PREFIX)
    observer = zenoh.open(zenoh.Config.from_file(str(rc.clients["observer"])))
    try:
        counts: dict[str, int] = {}
        modes: dict[str, set[str]] = {r: set() for r in robots}
        lock = threading.Lock()

        def on(sample) -> None:  # type: ignore[no-untyped-def]
            key = str(sample.key_expr)
            with lock:
                counts[key] = counts.get(key, 0) + 1
                parsed = keys.parse_robot_key(key)
                if parsed is not None and parsed[2] == "status":
                    st = decode(sample.payload.to_bytes(), Status)
                    assert isinstance(st, Status), st
                    modes[parsed[1]].add(st.mode)

        sub = observer.declare_subscriber(_key("**"), on)
        scn = ["--scenario", "paper-exp2", "--lockstep"]
        for r in robots:
            spawn("agent", "--id", r, *scn, *conf(f"robot.{r}"), ready=f"agent {r} ready")
        coordinators = [
            spawn("coordinator", "--name", "main", *scn, *conf("coordinator.main")),
            spawn(
                "coordinator", "--name", "standby", "--standby", *scn,
                *conf("coordinator.standby"),
            ),
        ]  # fmt: skip
        # (in lockstep a coordinator is ready once the plant's clock runs: no wait before)
        plant = spawn(
            "plant", *scn, "--seed", "1", "--duration", "2", "--wait-robots", *conf("plant"),
            ready="plant ready",
        )  # fmt: skip
        for child in coordinators:
            child.wait_for_line("coordinator")
        assert plant.proc.wait(timeout=60) == 0, plant.describe()
        time.sleep(0.2)
        sub.undeclare()
        with lock:
            assert counts.get(_key("clock"), 0) >= 100, counts  # 2 s at 50 Hz
            for r in robots:
                assert counts.get(_key(f"robot/{r}/wheels"), 0) >= 100, (r, counts)
                assert "tracking" in modes[r], (r, modes)
            for c in ("main", "standby"):
                assert counts.get(_key(f"coordinator/{c}/heartbeat"), 0) > 0, counts
            assert counts.get(_key("assignment"), 0) > 0 and counts.get(_key("leader"), 0) >= 100
    finally:
        observer.close()


def _key(rest: str) -> str:
    return f"formation/{FLEET}/{rest}"
