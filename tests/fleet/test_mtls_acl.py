"""The shipped Zenoh mTLS + access-control files, exercised with real sessions, as shipped.

Certificates come from deploy/security/gen-certs.sh (openssl); the router runs in this process
with deploy/zenoh/router-mtls.json5 (only the listen endpoint and certificate paths changed),
the clients with robot-mtls.json5 / coordinator-mtls.json5 / operator-mtls.json5 /
observer-mtls.json5 the same way. tests/bus/test_acl.py checks every identity and key against the
generator (bus_schemas.acl) with certificates from formation.launch.pki; this file checks that the
shipped files and the shell script fit together.

"Not received" is proven by ordering, not by waiting: a client's samples travel in order on
its one link, so once a later, allowed sample of the same session has arrived, an earlier
denied one that was not delivered was dropped by the router.
"""

from __future__ import annotations

import json
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

pytestmark = pytest.mark.zenoh

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
GEN_CERTS = DEPLOY / "security" / "gen-certs.sh"
FLEET = "demo"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("certs")
    subprocess.run(
        [
            "bash",
            str(GEN_CERTS),
            "-o",
            str(out / "fleet"),
            "--router-host",
            "localhost",
            "--router-host",
            "127.0.0.1",
            "r1",
            "r2",
        ],
        check=True,
        capture_output=True,
    )
    # an impostor: a certificate with CN "coordinator.main" from a CA the fleet does not trust
    subprocess.run(
        ["bash", str(GEN_CERTS), "-o", str(out / "rogue")], check=True, capture_output=True
    )
    return out


def _set(conf: zenoh.Config, key: str, value: object) -> None:
    conf.insert_json5(key, json.dumps(value))


@pytest.fixture(scope="module")
def router_port(certs: Path) -> Iterator[int]:
    port = _free_port()
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "router-mtls.json5"))
    _set(conf, "listen/endpoints", [f"tls/127.0.0.1:{port}"])
    tls = certs / "fleet" / "router"
    _set(conf, "transport/link/tls/root_ca_certificate", str(tls / "ca.pem"))
    _set(conf, "transport/link/tls/listen_private_key", str(tls / "key.pem"))
    _set(conf, "transport/link/tls/listen_certificate", str(tls / "cert.pem"))
    _set(conf, "adminspace/enabled", False)
    router = zenoh.open(conf)
    try:
        yield port
    finally:
        router.close()


def _client_conf(
    port: int,
    template: str,
    *,
    ca: Path | None,
    cert_dir: Path | None,
    host: str = "localhost",
) -> zenoh.Config:
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh" / template))
    _set(conf, "connect/endpoints", [f"tls/{host}:{port}"] if ca else [f"tcp/{host}:{port}"])
    # fail at once instead of the deployed "retry forever"
    _set(conf, "connect/timeout_ms", 0)
    _set(conf, "connect/exit_on_failure", True)
    if ca is not None:
        _set(conf, "transport/link/tls/root_ca_certificate", str(ca))
    if cert_dir is None:
        if ca is not None:
            _set(conf, "transport/link/tls/enable_mtls", False)
            _set(conf, "transport/link/tls/connect_private_key", None)
            _set(conf, "transport/link/tls/connect_certificate", None)
    else:
        _set(conf, "transport/link/tls/connect_private_key", str(cert_dir / "key.pem"))
        _set(conf, "transport/link/tls/connect_certificate", str(cert_dir / "cert.pem"))
    return conf


def _open(port: int, certs: Path, cn: str) -> zenoh.Session:
    """A client session with the fleet certificate of ``cn`` ("coordinator.main", "robot.r1")
    and the shipped config file of its kind."""
    fleet = certs / "fleet"
    template = cn.partition(".")[0] + "-mtls.json5"
    conf = _client_conf(port, template, ca=fleet / "ca" / "ca.pem", cert_dir=fleet / cn)
    return zenoh.open(conf)


class Inbox:
    """Samples (key, payload) received by a subscriber callback, thread-safe."""

    def __init__(self) -> None:
        self._items: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def keys(self) -> set[str]:
        with self._lock:
            return {k for k, _ in self._items}

    def has(self, key: str, payload: bytes) -> bool:
        with self._lock:
            return (key, payload) in self._items

    def wait(self, key: str, payload: bytes, timeout_s: float = 3.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.has(key, payload):
                return True
            time.sleep(0.005)
        return self.has(key, payload)


def _prime(publisher: zenoh.Session, key: str, inbox: Inbox, timeout_s: float = 3.0) -> None:
    """Put on ``key`` until ``inbox`` sees it: the route through the router is in place."""
    deadline = time.monotonic() + timeout_s
    n = 0
    while time.monotonic() < deadline:
        payload = f"prime-{n}".encode()
        publisher.put(key, payload)
        if inbox.wait(key, payload, timeout_s=0.1):
            return
        n += 1
    raise AssertionError(f"no route for {key}")


# ---------------------------------------------------------------------- authentication


def test_client_without_certificate_is_refused(router_port: int, certs: Path) -> None:
    conf = _client_conf(
        router_port, "robot-mtls.json5", ca=certs / "fleet" / "ca" / "ca.pem", cert_dir=None
    )
    with pytest.raises(zenoh.ZError):
        zenoh.open(conf)


def test_certificate_from_another_ca_is_refused(router_port: int, certs: Path) -> None:
    conf = _client_conf(
        router_port,
        "coordinator-mtls.json5",
        ca=certs / "fleet" / "ca" / "ca.pem",  # it trusts the router...
        cert_dir=certs / "rogue" / "coordinator.main",  # ...but the router does not trust it
    )
    with pytest.raises(zenoh.ZError):
        zenoh.open(conf)


def test_plain_tcp_client_is_refused(router_port: int) -> None:
    conf = _client_conf(router_port, "client.json5", ca=None, cert_dir=None, host="127.0.0.1")
    with pytest.raises(zenoh.ZError):
        zenoh.open(conf)


# ---------------------------------------------------------------------- authorisation


COORDINATOR_KEYS = [
    f"formation/{FLEET}/robot/r1/setpoint",
    f"formation/{FLEET}/slot/1",
    f"formation/{FLEET}/leader",
    f"formation/{FLEET}/assignment",
    f"formation/{FLEET}/setpoints",
    f"formation/{FLEET}/coordinator/main/heartbeat",
]


def test_access_control(router_port: int, certs: Path) -> None:
    observer = _open(router_port, certs, "observer")
    coordinator = _open(router_port, certs, "coordinator.main")
    operator = _open(router_port, certs, "operator")
    r1 = _open(router_port, certs, "robot.r1")
    r2 = _open(router_port, certs, "robot.r2")
    sessions = (r2, r1, operator, coordinator, observer)
    try:
        seen = Inbox()  # the observer reads the whole fleet
        r1_setpoint, r1_estop = Inbox(), Inbox()
        alive_seen = Inbox()
        subs = [
            observer.declare_subscriber(f"formation/{FLEET}/**", seen),
            r1.declare_subscriber(f"formation/{FLEET}/robot/r1/setpoint", r1_setpoint),
            r1.declare_subscriber(f"formation/{FLEET}/estop", r1_estop),
            coordinator.liveliness().declare_subscriber(
                f"formation/{FLEET}/alive/robot/*", alive_seen
            ),
        ]
        own_wheels_r1 = f"formation/{FLEET}/robot/r1/wheels"
        _prime(r1, own_wheels_r1, seen)
        _prime(r2, f"formation/{FLEET}/robot/r2/status", seen)
        _prime(coordinator, COORDINATOR_KEYS[0], seen)
        _prime(coordinator, COORDINATOR_KEYS[0], r1_setpoint)
        _prime(operator, f"formation/{FLEET}/estop", r1_estop)

        # 1. a robot certificate cannot put what only coordinators, localization or operators may
        forbidden_for_r1 = [
            *COORDINATOR_KEYS,
            f"formation/{FLEET}/estop",
            f"formation/{FLEET}/robot/r2/setpoint",
            f"formation/{FLEET}/robot/r1/pose",
            f"formation/{FLEET}/poses",
            f"formation/{FLEET}/robot/r2/wheels",  # another robot's wheels
            f"formation/{FLEET}/robot/r2/status",
        ]
        for key in forbidden_for_r1:
            r1.put(key, b"forged")
        r1.put(own_wheels_r1, b"after-forged")  # allowed: r1's own wheels
        r1.put(f"formation/{FLEET}/robot/r1/status", b"after-forged")  # and status
        assert seen.wait(own_wheels_r1, b"after-forged")
        assert seen.wait(f"formation/{FLEET}/robot/r1/status", b"after-forged")
        for key in forbidden_for_r1:
            assert not seen.has(key, b"forged"), key

        # 2. the coordinator certificate can, and r1 reads its setpoint
        for key in COORDINATOR_KEYS:
            coordinator.put(key, b"from-coordinator")
        for key in COORDINATOR_KEYS:
            assert seen.wait(key, b"from-coordinator"), key
        assert r1_setpoint.wait(COORDINATOR_KEYS[0], b"from-coordinator")
        # ...but not the e-stop, which only an operator puts
        coordinator.put(f"formation/{FLEET}/estop", b"coordinator-estop")
        operator.put(f"formation/{FLEET}/estop", b"operator-estop")
        assert r1_estop.wait(f"formation/{FLEET}/estop", b"operator-estop")
        assert not r1_estop.has(f"formation/{FLEET}/estop", b"coordinator-estop")

        # 3. r2 may put its own wheels, not r1's
        r2.put(own_wheels_r1, b"r2-forged")
        r2.put(f"formation/{FLEET}/robot/r2/wheels", b"r2-own")
        assert seen.wait(f"formation/{FLEET}/robot/r2/wheels", b"r2-own")
        assert not seen.has(own_wheels_r1, b"r2-forged")

        # 4. liveliness: r1 may declare its own token only
        forged_token = r1.liveliness().declare_token(f"formation/{FLEET}/alive/robot/r2")
        own_token = r1.liveliness().declare_token(f"formation/{FLEET}/alive/robot/r1")
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and not alive_seen.keys():
            time.sleep(0.005)
        time.sleep(0.1)  # declarations travel in order too; a little slack on top
        assert alive_seen.keys() == {f"formation/{FLEET}/alive/robot/r1"}
        forged_token.undeclare()
        own_token.undeclare()
        for sub in subs:
            sub.undeclare()
    finally:
        for session in sessions:
            session.close()


def test_only_the_operator_drives_the_virtual_leader(router_port: int, certs: Path) -> None:
    """Issue 28: the operator's commands (``operator/cmd_vel``, ``goal``, ``path``, ``shape``)
    reach the coordinators from the operator's certificate only; a robot's or a coordinator's
    forged twist is dropped by the router."""
    observer = _open(router_port, certs, "observer")
    coordinator = _open(router_port, certs, "coordinator.main")
    operator = _open(router_port, certs, "operator")
    r1 = _open(router_port, certs, "robot.r1")
    sessions = (r1, operator, coordinator, observer)
    ops = [f"formation/{FLEET}/operator/{leaf}" for leaf in ("cmd_vel", "goal", "path", "shape")]
    try:
        seen, commands = Inbox(), Inbox()
        # one subscription per key: a coordinator may not declare on operator/* (wider than
        # its grants), as formation coordinator does (coordinator/node/main.py)
        subs = [
            observer.declare_subscriber(f"formation/{FLEET}/**", seen),
            *(coordinator.declare_subscriber(key, commands) for key in ops),
        ]
        own_wheels_r1 = f"formation/{FLEET}/robot/r1/wheels"
        _prime(r1, own_wheels_r1, seen)
        _prime(coordinator, COORDINATOR_KEYS[0], seen)
        _prime(operator, ops[0], commands)
        for key in ops:
            r1.put(key, b"robot-forged")
            coordinator.put(key, b"coordinator-forged")
        r1.put(own_wheels_r1, b"after-forged")  # later samples of the same sessions, allowed
        coordinator.put(COORDINATOR_KEYS[0], b"after-forged")
        for key in ops:
            operator.put(key, b"from-operator")
        assert seen.wait(own_wheels_r1, b"after-forged")
        assert seen.wait(COORDINATOR_KEYS[0], b"after-forged")
        for key in ops:
            assert commands.wait(key, b"from-operator"), key
            assert not commands.has(key, b"robot-forged"), key
            # (the coordinator's own forged put reaches its own subscriber inside its session;
            # the router never forwarded it: the observer did not get it)
            assert not seen.has(key, b"robot-forged") and not seen.has(key, b"coordinator-forged")
            assert seen.has(key, b"from-operator"), key
        for sub in subs:
            sub.undeclare()
    finally:
        for session in sessions:
            session.close()


def test_a_foxglove_teleop_reaches_the_coordinators_only_from_the_operator(
    router_port: int, certs: Path
) -> None:
    """Issue 28 under ``--secure``: a Foxglove client's Teleop publish, translated by the live
    server (formation.live.foxglove_ops), reaches a coordinator when the server holds the
    operator's identity; a server that holds only the observer's puts the same twists and the
    router drops every one (the live server cannot lift an identity's rights)."""
    import asyncio

    from support.foxglove_fleet import publish_twists

    from bus_schemas import CmdVel, DecodeError, decode
    from formation.live.foxglove import start_live

    observer = _open(router_port, certs, "observer")
    operator = _open(router_port, certs, "operator")
    coordinator = _open(router_port, certs, "coordinator.main")
    key = f"formation/{FLEET}/operator/cmd_vel"
    got = Inbox()
    sub = coordinator.declare_subscriber(key, got)
    _prime(operator, key, got)  # the route from the operator's session is in place
    as_observer = start_live(observer, FLEET, port=0, commands=observer)
    as_operator = start_live(observer, FLEET, port=0, commands=operator)

    def twist(v_mps: float) -> dict[str, dict[str, float]]:
        return {"linear": {"x": v_mps, "y": 0.0, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0}}

    def speeds() -> list[float]:
        with got._lock:
            items = list(got._items)
        msgs = [decode(p, CmdVel) for k, p in items if not p.startswith(b"prime-")]
        return [m.v_mps for m in msgs if not isinstance(m, DecodeError)]

    try:
        asyncio.run(publish_twists(as_observer.url, twist(0.01), 0.5, "/cmd_vel"))
        asyncio.run(publish_twists(as_operator.url, twist(0.06), 0.5, "/cmd_vel"))
        deadline = time.monotonic() + 5.0
        while speeds().count(0.06) < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)  # the observer's twists went out a whole half second before these
        received = speeds()
    finally:
        as_observer.close()
        as_operator.close()
        sub.undeclare()
        for s in (observer, operator, coordinator):
            s.close()
    # both servers took and put the twists: the router is what tells them apart
    assert as_observer.live.operator.accepted >= 5
    assert as_operator.live.operator.accepted >= 5
    assert received.count(0.06) >= 5, received
    assert 0.01 not in received, received
