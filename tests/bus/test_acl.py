"""The access control generated from the bus contract (bus_schemas.acl), statically and live.

Static: for every identity of a fleet and every concrete key of the contract, what the generated
``access_control`` allows is exactly what the issue asks (the expectations below are written out
by hand, not derived from bus_schemas.acl.KEY_ROLES). Live: a real Zenoh router in this process
with mTLS and the generated config, a client session per identity with a certificate from
formation.launch.pki: each identity's representative keys arrive, every other key it publishes is
dropped, forged liveliness tokens never appear, sessions without a fleet certificate are refused.

"Not received" is proven by ordering, not by waiting: a session's messages travel in order on
its one link, so once a later, allowed message of the same session has arrived, an earlier
refused one that did not arrive was dropped by the router.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.bus_inbox import Inbox

from bus_schemas import acl, keys
from bus_schemas.acl import Access, Identity, Kind

pytestmark = pytest.mark.shares_cpu

FLEET = "demo"
ROBOTS = ("r1", "r2", "r3")  # r3 is run by agent host h1
IDENTS = (
    acl.robot("r1"),
    acl.robot("r2"),
    acl.agent_host("h1", ["r3"]),
    acl.coordinator("main"),
    acl.coordinator("standby"),
    Identity(Kind.LOCALIZATION),
    Identity(Kind.PLANT),
    Identity(Kind.OPERATOR),
    Identity(Kind.OBSERVER, "rec"),
)
REPO = Path(__file__).resolve().parents[2]


def _f(rest: str) -> str:
    return f"formation/{FLEET}/{rest}"


def contract_keys() -> dict[str, str]:
    """Every concrete key of the contract for ROBOTS, coordinators main/standby, host h1."""
    out: dict[str, str] = {}
    for leaf, template in keys.KEY_TEMPLATES.items():
        names = (*ROBOTS, "h1") if leaf == keys.ESTOP_HELD else ("main", "standby", "h1")
        ids = {"robot": ROBOTS, "name": names, "slot": ("0", "3")}
        variants = [template]
        for field, values in ids.items():
            if "{" + field + "}" in template:
                variants = [v.replace("{" + field + "}", x) for v in variants for x in values]
        for v in variants:
            if "{name}" not in v and "{robot}" not in v:
                key = v.format(fleet=FLEET)
                if leaf in (keys.HOST_WHEELS, keys.HOST_STATUS) and "/host/h1/" not in key:
                    continue  # host keys exist for host names only
                coordinator_key = leaf in (
                    keys.HEARTBEAT,
                    keys.COORDINATOR_STATUS,
                    keys.ALIVE_COORDINATOR,
                )
                if coordinator_key and "/h1" in key:
                    continue
                out[key] = leaf
    return out


KEYS = contract_keys()
TOKENS = {k for k, leaf in KEYS.items() if leaf.startswith("alive_")}
DATA = set(KEYS) - TOKENS
CAMERA_STATUS = {_f(f"camera/{n}/status") for n in ("main", "standby", "h1")}


def _robot_keys(r: str, *leaves: str) -> set[str]:
    return {_f(f"robot/{r}/{leaf}") for leaf in leaves}


# What each identity may publish / declare, written out from the issue (not from KEY_ROLES).
EXPECT_PUBLISH: dict[str, set[str]] = {
    "robot.r1": _robot_keys("r1", "wheels", "status"),
    "robot.r2": _robot_keys("r2", "wheels", "status"),
    "host.h1": {_f("host/h1/wheels"), _f("host/h1/status")},
    "coordinator.main": {
        _f("leader"),
        _f("slot/0"),
        _f("slot/3"),
        *(_f(f"robot/{r}/setpoint") for r in ROBOTS),
        _f("setpoints"),
        _f("movers"),  # issue 30: the moving obstacles
        _f("assignment"),
        _f("coordinator/main/heartbeat"),
        _f("coordinator/main/status"),
        _f("fault"),  # scripted faults' notices (issue 32)
    },
    "localization": {*(_f(f"robot/{r}/pose") for r in ROBOTS), _f("poses"), *CAMERA_STATUS},
    "plant": {
        *(_f(f"robot/{r}/pose") for r in ROBOTS),
        _f("poses"),
        *(_f(f"robot/{r}/truth") for r in ROBOTS),
        _f("truths"),
        _f("clock"),
        _f("plant/status"),
    },
    # issue 28: only the operator drives the virtual leader
    "operator": {
        _f("estop"),
        _f("disturbance"),
        _f("operator/cmd_vel"),
        _f("operator/goal"),
        _f("operator/path"),
        _f("operator/shape"),
        _f("operator/obstacle"),
        _f("fault"),
    },
    "observer.rec": set(),
}
EXPECT_PUBLISH["coordinator.standby"] = {
    k.replace("/main/", "/standby/") for k in EXPECT_PUBLISH["coordinator.main"]
}
EXPECT_TOKEN: dict[str, set[str]] = {
    "robot.r1": {_f("alive/robot/r1")},
    "robot.r2": {_f("alive/robot/r2")},
    "host.h1": {_f("alive/robot/r3")},
    "coordinator.main": {_f("alive/coordinator/main")},
    "coordinator.standby": {_f("alive/coordinator/standby")},
    "plant": {_f("alive/plant")},
}
# What each identity may read (subscribe to and be delivered).
_ALL_POSES = {*(_f(f"robot/{r}/pose") for r in ROBOTS), _f("poses")}
# every status: robots and hosts learn which neighbours are TRACKING (cooperative)
_ALL_STATUS = {*(_f(f"robot/{r}/status") for r in ROBOTS), _f("host/h1/status")}
EXPECT_READ: dict[str, set[str]] = {
    "robot.r1": {
        _f("robot/r1/setpoint"),
        _f("setpoints"),
        _f("movers"),
        *_ALL_POSES,
        *_ALL_STATUS,
        _f("estop"),
        _f("clock"),
        _f("fault"),
    },
    "host.h1": {
        _f("setpoints"),
        _f("movers"),
        _f("poses"),
        *_ALL_STATUS,
        _f("estop"),
        _f("clock"),
        _f("fault"),
    },
    "coordinator.main": {
        *_ALL_POSES,
        *(_f(f"robot/{r}/status") for r in ROBOTS),
        _f("host/h1/status"),
        _f("assignment"),
        _f("leader"),  # a standby checks trajectory origins against it (coordinator.core.election)
        _f("estop"),
        _f("clock"),
        _f("fault"),  # an operator's request (formation fault --at T)
        *(_f(f"coordinator/{c}/{x}") for c in ("main", "standby") for x in ("heartbeat", "status")),
        # the operator's commands (a standby keeps them to continue after a takeover)
        _f("operator/cmd_vel"),
        _f("operator/goal"),
        _f("operator/path"),
        _f("operator/shape"),
        _f("operator/obstacle"),
    },
    "localization": {*(_f(f"robot/{r}/truth") for r in ROBOTS), _f("truths")},
    "plant": {
        *(_f(f"robot/{r}/wheels") for r in ROBOTS),
        _f("host/h1/wheels"),
        _f("disturbance"),
        _f("leader"),
        _f("fault"),
    },
    "operator": set(DATA),
    "observer.rec": set(DATA),
}
EXPECT_READ["robot.r2"] = {
    k.replace("robot/r1/setpoint", "robot/r2/setpoint") for k in EXPECT_READ["robot.r1"]
}
EXPECT_READ["coordinator.standby"] = EXPECT_READ["coordinator.main"]
EXPECT_WATCH: dict[str, set[str]] = {
    "coordinator.main": set(TOKENS),
    "coordinator.standby": set(TOKENS),
    "plant": {k for k in TOKENS if "/alive/plant" not in k},
    "operator": set(TOKENS),
    "observer.rec": set(TOKENS),
}


# The latched e-stop state (robot_agent.core.estop): coordinators answer queries on `estop`; an
# agent
# or agent host answers on its own `estop/held/<name>` only (the engagements it holds); agents,
# hosts, coordinators and the operator's tool ask both.
_HELD = {_f(f"estop/held/{n}") for n in (*ROBOTS, "h1")}
EXPECT_ANSWER: dict[str, set[str]] = {
    "coordinator.main": {_f("estop")},
    "coordinator.standby": {_f("estop")},
    "robot.r1": {_f("estop/held/r1")},
    "robot.r2": {_f("estop/held/r2")},
    "host.h1": {_f("estop/held/h1")},
}
# an agent is sent the queries of `estop/held/*` (it answers its own key among them)
EXPECT_ASKED: dict[str, set[str]] = {
    cn: {*EXPECT_ANSWER[cn], *_HELD} for cn in ("robot.r1", "robot.r2", "host.h1")
}
EXPECT_ASKED |= {cn: EXPECT_ANSWER[cn] for cn in ("coordinator.main", "coordinator.standby")}
EXPECT_ASK: dict[str, set[str]] = {
    cn: {_f("estop"), *_HELD}
    for cn in ("robot.r1", "robot.r2", "host.h1", "coordinator.main", "coordinator.standby",
               "operator")
}  # fmt: skip


@pytest.fixture(scope="module")
def acl_section() -> dict[str, object]:
    return acl.access_control(IDENTS, FLEET)


@pytest.mark.parametrize("ident", IDENTS, ids=[i.cn for i in IDENTS])
def test_static_permissions_match_the_contract(
    ident: Identity, acl_section: dict[str, object]
) -> None:
    cn = ident.cn
    for access, universe, expect in (
        (Access.PUBLISH, DATA, EXPECT_PUBLISH.get(cn, set())),
        (Access.READ, DATA, EXPECT_READ.get(cn, set())),
        (Access.TOKEN, TOKENS, EXPECT_TOKEN.get(cn, set())),
        (Access.WATCH, TOKENS, EXPECT_WATCH.get(cn, set())),
        (Access.ANSWER, DATA, EXPECT_ANSWER.get(cn, set())),
        (Access.ASK, DATA, EXPECT_ASK.get(cn, set())),
        (Access.ASKED, DATA, EXPECT_ASKED.get(cn, set())),
    ):
        allowed = {k for k in universe if acl.may(acl_section, cn, access, k)}
        assert allowed == expect, (cn, access, sorted(allowed ^ expect))
    # nothing at all outside the fleet, the admin space or another fleet
    for key in ("@/router/local", "formation/other/estop", "formation/demo2/robot/r1/setpoint"):
        for access in Access:
            assert not acl.may(acl_section, cn, access, key), (cn, access, key)


def test_an_unknown_certificate_name_may_nothing(acl_section: dict[str, object]) -> None:
    for key in KEYS:
        for access in Access:
            for cn in ("r1", "robot", "robot.r9", "coordinator", "operator.x", "ROBOT.r1"):
                assert not acl.may(acl_section, cn, access, key)


def test_every_contract_key_has_declared_roles() -> None:
    assert set(acl.KEY_ROLES) == set(keys.KEY_TEMPLATES)


def test_identity_names_are_checked() -> None:
    for bad in (("robot", "R1"), ("robot", ""), ("coordinator", "a/b"), ("host", "*")):
        with pytest.raises(ValueError):
            Identity(Kind(bad[0]), bad[1])
    with pytest.raises(ValueError):
        Identity.parse("admin.x")
    assert Identity.parse("robot.r1") == acl.robot("r1")
    with pytest.raises(ValueError):
        acl.fleet_identities(["r1", "r1"])


def test_keyexpr_includes() -> None:
    inc = acl.keyexpr_includes
    assert inc("a/*/c", "a/b/c") and not inc("a/*/c", "a/b/d/c") and not inc("a/*/c", "a/c")
    assert inc("a/**", "a") and inc("a/**", "a/b/c") and inc("a/**/c", "a/c")
    assert inc("a/*/c", "a/*/c") and not inc("a/b/c", "a/*/c") and not inc("a/*", "a/**")


# ---------------------------------------------------------------------- shipped files


def test_shipped_deploy_configs_are_the_generated_ones() -> None:
    generated = acl.deploy_configs(acl.deploy_identities())
    shipped = {p.name: p.read_text() for p in (REPO / "deploy" / "zenoh").glob("*.json5")}
    assert shipped == generated, "regenerate: formation acl --out deploy/zenoh"


def test_generated_configs_are_valid_zenoh_configs() -> None:
    zenoh = pytest.importorskip("zenoh")
    for name, text in acl.deploy_configs(acl.deploy_identities()).items():
        conf = zenoh.Config.from_json5(text)  # strict: an unknown key fails
        lease = json.loads(conf.get_json("transport/link/tx/lease"))
        assert lease < 1000, name
        assert json.loads(conf.get_json("transport/link/rx/max_message_size")) <= 256 * 1024
        assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
        if name != "client.json5":
            assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
            assert json.loads(conf.get_json("transport/link/protocols")) == ["tls"]


# ---------------------------------------------------------------------- live router


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    from formation.launch.pki import make_run_pki

    root = tmp_path_factory.mktemp("pki")
    fleet = make_run_pki(root / "fleet", IDENTS)
    rogue = make_run_pki(root / "rogue", [acl.coordinator("main")])  # same CN, another CA
    return fleet, rogue


@pytest.fixture(scope="module")
def router(pki) -> Iterator[int]:  # type: ignore[no-untyped-def]
    zenoh = pytest.importorskip("zenoh")
    fleet, _ = pki
    port = _free_port()
    conf = acl.router_config(IDENTS, fleet.router.tls(), listen=[f"tls/127.0.0.1:{port}"])
    session = zenoh.open(zenoh.Config.from_json5(acl.to_json5(conf)))
    try:
        yield port
    finally:
        session.close()


def _client(port: int, files: acl.TlsFiles):  # type: ignore[no-untyped-def]
    import zenoh

    conf = acl.client_config(files, connect=[f"tls/localhost:{port}"], retry_forever=False)
    return zenoh.open(zenoh.Config.from_json5(acl.to_json5(conf)))


def _clients(port: int, fleet, *cns: str) -> list:  # type: ignore[no-untyped-def]
    """A session per certificate name ``cns`` of the run PKI ``fleet``, in order."""
    return [_client(port, fleet.identities[cn].tls()) for cn in cns]


def _prime(session, key: str, inbox: Inbox, timeout_s: float = 5.0) -> None:  # type: ignore[no-untyped-def]
    """Put on ``key`` until ``inbox`` sees it: the route through the router is in place.
    ``session`` is a Session, or a Publisher of ``key``."""
    deadline = time.monotonic() + timeout_s
    n = 0
    is_publisher = not hasattr(session, "declare_publisher")
    while time.monotonic() < deadline:
        payload = f"prime-{n}".encode()
        if is_publisher:
            session.put(payload)
        else:
            session.put(key, payload)
        if inbox.wait(key, payload, timeout_s=0.1):
            return
        n += 1
    raise AssertionError(f"no route for {key}")


# Representative keys per publishing identity: (allowed, refused). Each list of refused keys
# includes what an attacker with that certificate would forge first.
LIVE_PUBLISH: dict[str, tuple[list[str], list[str]]] = {
    "robot.r1": (
        [_f("robot/r1/wheels"), _f("robot/r1/status")],
        [
            _f("robot/r1/setpoint"),
            _f("robot/r2/setpoint"),
            _f("setpoints"),
            _f("robot/r1/pose"),
            _f("robot/r2/pose"),
            _f("poses"),
            _f("robot/r2/wheels"),
            _f("robot/r2/status"),
            _f("estop"),
            _f("coordinator/main/heartbeat"),
            _f("assignment"),
            _f("clock"),
            _f("camera/camera/status"),
        ],
    ),
    "host.h1": (
        [_f("host/h1/wheels"), _f("host/h1/status")],
        [_f("robot/r3/wheels"), _f("setpoints"), _f("estop"), _f("poses")],
    ),
    "coordinator.main": (
        [
            _f("leader"),
            _f("slot/3"),
            _f("robot/r2/setpoint"),
            _f("setpoints"),
            _f("assignment"),
            _f("coordinator/main/heartbeat"),
            _f("coordinator/main/status"),
        ],
        [
            _f("coordinator/standby/heartbeat"),
            _f("estop"),
            _f("robot/r1/pose"),
            _f("poses"),
            _f("robot/r1/wheels"),
            _f("clock"),
            _f("disturbance"),
            _f("camera/camera/status"),
        ],
    ),
    "localization": (
        [_f("robot/r1/pose"), _f("poses"), _f("camera/camera/status")],
        [_f("robot/r1/setpoint"), _f("robot/r1/truth"), _f("estop"), _f("clock")],
    ),
    "plant": (
        [_f("robot/r1/pose"), _f("poses"), _f("robot/r1/truth"), _f("clock"), _f("plant/status")],
        [_f("robot/r1/setpoint"), _f("estop"), _f("leader"), _f("robot/r1/wheels")],
    ),
    "operator": (
        [_f("estop"), _f("disturbance")],
        [_f("robot/r1/setpoint"), _f("setpoints"), _f("robot/r1/pose"), _f("leader")],
    ),
}


@pytest.mark.zenoh
def test_live_publish_per_identity(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    fleet, _ = pki
    witness = _client(router, fleet.identities["observer.rec"].tls())
    try:
        inbox = Inbox()
        sub = witness.declare_subscriber(_f("**"), inbox)
        for cn, (allowed, refused) in LIVE_PUBLISH.items():
            session = _client(router, fleet.identities[cn].tls())
            try:
                # the nodes publish through declared publishers: use those for allowed keys (a
                # new publisher learns of the subscribers first: prime each)
                pubs = [session.declare_publisher(key) for key in allowed]
                for pub in pubs:
                    _prime(pub, str(pub.key_expr), inbox)
                tag = cn.encode()
                for key in refused:
                    session.put(key, b"forged-" + tag)
                for pub in pubs:
                    pub.put(b"ok-" + tag)
                for key in allowed:
                    assert inbox.wait(key, b"ok-" + tag), (cn, key)
                for key in refused:
                    assert not inbox.has(key, b"forged-" + tag), (cn, key)
            finally:
                session.close()
        sub.undeclare()
    finally:
        witness.close()


@pytest.mark.zenoh
def test_live_reads_are_limited(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    """r1 reads its own setpoint, never r2's, even subscribed to everything."""
    fleet, _ = pki
    coord = _client(router, fleet.identities["coordinator.main"].tls())
    r1 = _client(router, fleet.identities["robot.r1"].tls())
    try:
        own, everything = Inbox(), Inbox()
        subs = [
            r1.declare_subscriber(_f("robot/r1/setpoint"), own),
            r1.declare_subscriber(_f("**"), everything),
        ]
        _prime(coord, _f("robot/r1/setpoint"), own)
        coord.put(_f("robot/r2/setpoint"), b"not-for-r1")
        coord.put(_f("slot/3"), b"not-for-r1")
        coord.put(_f("robot/r1/setpoint"), b"fence")
        assert own.wait(_f("robot/r1/setpoint"), b"fence")
        assert everything.keys() <= {_f("robot/r1/setpoint")}
        for sub in subs:
            sub.undeclare()
    finally:
        r1.close()
        coord.close()


def _ask(session, key: str) -> list[bytes]:  # type: ignore[no-untyped-def]
    """The payloads of the replies to one query of ``key`` (none when the ACL refuses it)."""
    out: list[bytes] = []
    for reply in session.get(key, timeout=1.0):
        if reply.ok is not None:
            out.append(bytes(reply.ok.payload))
    return out


@pytest.mark.zenoh
def test_live_estop_state_query(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    """A coordinator answers the latched e-stop query; a robot and the operator get the answer;
    an observer's query and a robot's queryable are refused (robot_agent.core.estop)."""
    fleet, _ = pki
    coord, r1, r2, op, obs = _clients(
        router, fleet, "coordinator.main", "robot.r1", "robot.r2", "operator", "observer.rec"
    )
    key = _f("estop")
    try:
        coord_q = coord.declare_queryable(key, lambda q: q.reply(key, b"latched"))
        forged_q = r2.declare_queryable(key, lambda q: q.reply(key, b"forged"))
        deadline = time.monotonic() + 5.0
        answers: list[bytes] = []
        while time.monotonic() < deadline and not answers:
            answers = _ask(r1, key)
        assert answers == [b"latched"]  # the robot's forged queryable never answers
        assert _ask(op, key) == [b"latched"]
        assert _ask(obs, key) == []
        coord_q.undeclare()
        forged_q.undeclare()
    finally:
        for session in (coord, r1, r2, op, obs):
            session.close()


@pytest.mark.zenoh
def test_live_estop_held_query(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    """An agent answers the engagements it holds on its own ``estop/held/<robot>`` only: a
    coordinator's, a robot's and the operator's query of ``estop/held/*`` get r1's answer; r2's
    queryable on r1's key, r1's on ``estop`` (where releases are) and an observer's query are
    refused. (The askers hold no queryable of their own: a session answers its own queries
    locally, without the router.)"""
    fleet, _ = pki
    coord, r1, r2, r3, op, obs = _clients(
        router, fleet, "coordinator.main", "robot.r1", "robot.r2", "host.h1", "operator",
        "observer.rec",
    )  # fmt: skip
    held_r1, held_all = _f("estop/held/r1"), _f("estop/held/*")
    try:
        own_q = r1.declare_queryable(held_r1, lambda q: q.reply(held_r1, b"held"))
        forged_q = r2.declare_queryable(held_r1, lambda q: q.reply(held_r1, b"forged"))
        forged_estop = r1.declare_queryable(_f("estop"), lambda q: q.reply(_f("estop"), b"rel"))
        deadline = time.monotonic() + 5.0
        answers: list[bytes] = []
        while time.monotonic() < deadline and not answers:
            answers = _ask(coord, held_all)
        assert answers == [b"held"]  # r2's forged answer for r1 never arrives
        assert _ask(r3, held_all) == [b"held"]
        assert _ask(op, held_all) == [b"held"]
        assert _ask(coord, _f("estop")) == []  # r1 may not answer where releases are
        assert _ask(obs, held_all) == []
        for q in (own_q, forged_q, forged_estop):
            q.undeclare()
    finally:
        for session in (coord, r1, r2, r3, op, obs):
            session.close()


@pytest.mark.zenoh
def test_live_liveliness_tokens(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    """A robot declares only its own token; the coordinator sees it (also with history), and a
    robot cannot watch tokens at all."""
    fleet, _ = pki
    coord = _client(router, fleet.identities["coordinator.main"].tls())
    r1 = _client(router, fleet.identities["robot.r1"].tls())
    host = _client(router, fleet.identities["host.h1"].tls())
    standby = _client(router, fleet.identities["coordinator.standby"].tls())
    try:
        seen, too_wide = Inbox(), Inbox()
        # history: the tokens below may reach the router before this watcher's declaration
        watch = coord.liveliness().declare_subscriber(_f("alive/robot/*"), seen, history=True)
        # wider than any grant (alive/** is not within alive/robot/*, alive/coordinator/*,
        # alive/plant): that watcher gets nothing, on a session of its own
        wide_watch = standby.liveliness().declare_subscriber(_f("alive/**"), too_wide)
        robot_watch = Inbox()
        r1_watch = r1.liveliness().declare_subscriber(_f("alive/**"), robot_watch)
        forged = r1.liveliness().declare_token(_f("alive/robot/r2"))
        forged_c = r1.liveliness().declare_token(_f("alive/coordinator/main"))
        own = r1.liveliness().declare_token(_f("alive/robot/r1"))
        h_forged = host.liveliness().declare_token(_f("alive/robot/r1"))
        h_own = host.liveliness().declare_token(_f("alive/robot/r3"))
        assert seen.wait(_f("alive/robot/r1"))
        assert seen.wait(_f("alive/robot/r3"))
        time.sleep(0.1)  # declarations travel in order; a little slack on top
        assert seen.keys() == {_f("alive/robot/r1"), _f("alive/robot/r3")}
        # a late watcher with history gets the current tokens (liveliness_query allowed)
        late = Inbox()
        late_watch = coord.liveliness().declare_subscriber(_f("alive/robot/*"), late, history=True)
        assert late.wait(_f("alive/robot/r1")) and late.wait(_f("alive/robot/r3"))
        # robots may not watch liveliness: r1's watcher sees only the tokens of its own session
        # (delivered locally), never the host's
        own_session = {_f("alive/robot/r2"), _f("alive/coordinator/main"), _f("alive/robot/r1")}
        assert robot_watch.keys() <= own_session
        assert too_wide.keys() == set()
        for t in (forged, forged_c, own, h_forged, h_own):
            t.undeclare()
        assert seen.wait(_f("alive/robot/r1")) and _wait_delete(seen, _f("alive/robot/r1"))
        for s in (watch, wide_watch, r1_watch, late_watch):
            s.undeclare()
    finally:
        for s in (standby, host, r1, coord):
            s.close()


def _wait_delete(inbox: Inbox, key: str, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with inbox._lock:
            if any(k == key and "DELETE" in kind.upper() for k, _, kind in inbox.items):
                return True
        time.sleep(0.005)
    return False


# ---------------------------------------------------------------------- authentication


@pytest.mark.zenoh
def test_client_without_certificate_is_refused(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    import zenoh

    fleet, _ = pki
    conf = acl.client_config(
        fleet.identities["operator"].tls(), connect=[f"tls/localhost:{router}"], retry_forever=False
    )
    tls = conf["transport"]["link"]["tls"]
    tls.update(enable_mtls=False, connect_private_key=None, connect_certificate=None)
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


@pytest.mark.zenoh
def test_certificate_from_another_ca_is_refused(router: int, pki) -> None:  # type: ignore[no-untyped-def]
    import zenoh

    fleet, rogue = pki
    files = rogue.identities["coordinator.main"].tls()
    # it trusts the router, but the router does not trust its certificate
    files = acl.TlsFiles(ca=str(fleet.ca), cert=files.cert, key=files.key)
    with pytest.raises(zenoh.ZError):
        _client(router, files)


@pytest.mark.zenoh
def test_plain_tcp_client_is_refused(router: int) -> None:
    import zenoh

    conf = {
        "mode": "client",
        "connect": {"endpoints": [f"tcp/127.0.0.1:{router}"], "timeout_ms": 0},
        "scouting": {"multicast": {"enabled": False}},
    }
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
