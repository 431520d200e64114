"""Zenoh access control and session configs generated from the bus contract (stdlib only).

Who may publish, read, declare or watch each key of ``bus_schemas.keys.KEY_TEMPLATES`` is declared
once, in :data:`KEY_ROLES`; from it and a list of :class:`Identity` this module builds

- the router's ``access_control`` section (default deny; one subject and one policy per identity,
  matched by the certificate's common name, CN), :func:`access_control`;
- the router's whole Zenoh config (mTLS only, multicast off, short lease, message size cap),
  :func:`router_config`, and each process's client config, :func:`client_config`;
- the JSON5 text of both (:func:`to_json5`) and the files shipped under ``deploy/zenoh/``
  (:func:`write_deploy_configs`, ``formation acl``).

Identities and their certificate CNs (``<kind>.<name>``; ``.`` is in no id alphabet, so a CN can
never be read as another kind's):

=====================  ===========================  ============================================
identity               CN                           may publish (everything else is refused)
=====================  ===========================  ============================================
robot ``<id>``         ``robot.<id>``               its own wheels, status, liveliness token
agent host ``<name>``  ``host.<name>``              its host wheels/status, its robots' tokens
coordinator ``<n>``    ``coordinator.<n>``          leader, slots, setpoints (both forms),
                                                    assignment, its heartbeat, status, token
localization           ``localization[.<name>]``    poses (both forms)
plant (simulation)     ``plant``                    poses, truth, clock, its status and token
operator ``<name>``    ``operator[.<name>]``        e-stop, disturbances
observer ``<name>``    ``observer[.<name>]``        nothing (recorder, dashboards, ``top``)
=====================  ===========================  ============================================

Each identity may read (subscribe to, and be delivered) what its process reads; the operator and
observers read the whole fleet. Zenoh checks ingress messages (from the identity to the router)
and egress messages (from the router to the identity) separately, so a grant is a pair:
publishing key K is ``put``/``delete`` ingress on K, reading K is ``declare_subscriber`` ingress
and ``put``/``delete`` egress on K; a liveliness token is ``liveliness_token`` ingress; watching
tokens is ``declare_liveliness_subscriber``/``liveliness_query`` ingress and ``liveliness_token``
egress; an identity that publishes is also told of every subscriber of the fleet
(``declare_subscriber`` egress on ``formation/<fleet>/**``), without which its declared publishers
do not send to wide subscribers such as a recorder's (tests/test_acl.py checks each against a real
router).
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, Final

from bus_schemas import keys

# --- identities ------------------------------------------------------------------------------


class Kind(StrEnum):
    """What an identity is; the first part of its certificate CN."""

    ROBOT = "robot"
    HOST = "host"
    COORDINATOR = "coordinator"
    LOCALIZATION = "localization"
    PLANT = "plant"
    OPERATOR = "operator"
    OBSERVER = "observer"


_NAMED: Final = frozenset({Kind.ROBOT, Kind.HOST, Kind.COORDINATOR})  # a name is required
_READ_ALL: Final = frozenset({Kind.OPERATOR, Kind.OBSERVER})
CN_SEPARATOR: Final = "."


@dataclass(frozen=True)
class Identity:
    """One process identity: its kind, its name (robot id, coordinator or host name, optional
    for the others) and, for an agent host, the robots it runs."""

    kind: Kind
    name: str = ""
    robots: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", Kind(self.kind))
        object.__setattr__(self, "robots", tuple(self.robots))
        if self.kind in _NAMED and not self.name:
            raise ValueError(f"a {self.kind} identity needs a name")
        if self.kind is Kind.ROBOT:
            keys.check_robot_id(self.name)
        elif self.name:
            keys.check_name(self.name)
        for r in self.robots:
            keys.check_robot_id(r)
        if self.robots and self.kind is not Kind.HOST:
            raise ValueError("only an agent host identity runs robots")

    @property
    def cn(self) -> str:
        """The certificate common name of this identity (``robot.r1``, ``plant``, ...)."""
        return f"{self.kind}{CN_SEPARATOR}{self.name}" if self.name else str(self.kind)

    @classmethod
    def parse(cls, cn: str) -> Identity:
        """The identity of a CN made by :attr:`cn` (an agent host's robots are not in it)."""
        kind, _, name = cn.partition(CN_SEPARATOR)
        return cls(Kind(kind), name)


def robot(robot_id: str) -> Identity:
    """The identity of robot ``robot_id``'s agent."""
    return Identity(Kind.ROBOT, robot_id)


def coordinator(name: str) -> Identity:
    """The identity of coordinator instance ``name``."""
    return Identity(Kind.COORDINATOR, name)


def agent_host(name: str, robots: Iterable[str]) -> Identity:
    """The identity of agent host ``name`` running ``robots``."""
    return Identity(Kind.HOST, name, tuple(robots))


def fleet_identities(
    robots: Iterable[str],
    coordinators: Iterable[str] = ("main",),
    *,
    localization: bool = True,
    plant: bool = False,
    operators: Iterable[str] = ("",),
    observers: Iterable[str] = ("",),
    hosts: Mapping[str, Iterable[str]] | None = None,
) -> tuple[Identity, ...]:
    """Every identity of a fleet, in a stable order (robots, hosts, coordinators, ...)."""
    out = [robot(r) for r in robots]
    out += [agent_host(h, rs) for h, rs in (hosts or {}).items()]
    out += [coordinator(c) for c in coordinators]
    if localization:
        out.append(Identity(Kind.LOCALIZATION))
    if plant:
        out.append(Identity(Kind.PLANT))
    out += [Identity(Kind.OPERATOR, n) for n in operators]
    out += [Identity(Kind.OBSERVER, n) for n in observers]
    cns = [i.cn for i in out]
    if len(set(cns)) != len(cns):
        raise ValueError(f"duplicate identities: {sorted(c for c in cns if cns.count(c) > 1)}")
    return tuple(out)


# --- the role of every key -------------------------------------------------------------------


class Access(StrEnum):
    """What an identity does with a key."""

    PUBLISH = "publish"  # put / delete samples
    READ = "read"  # subscribe and be delivered samples
    TOKEN = "token"  # declare a liveliness token
    WATCH = "watch"  # subscribe to / query liveliness tokens
    ANSWER = "answer"  # declare a queryable and reply to the queries it is sent
    ASK = "ask"  # query a key and be delivered the replies


# (flow, messages) pairs that each access needs at the router.
ZENOH_MESSAGES: Final[dict[Access, tuple[tuple[str, tuple[str, ...]], ...]]] = {
    Access.PUBLISH: (("ingress", ("put", "delete")),),
    Access.READ: (("ingress", ("declare_subscriber",)), ("egress", ("put", "delete"))),
    Access.TOKEN: (("ingress", ("liveliness_token",)),),
    Access.WATCH: (
        ("ingress", ("declare_liveliness_subscriber", "liveliness_query")),
        ("egress", ("liveliness_token",)),
    ),
    Access.ANSWER: (("ingress", ("declare_queryable", "reply")), ("egress", ("query",))),
    Access.ASK: (("ingress", ("query",)), ("egress", ("reply",))),
}

# Who: a Kind (any identity of that kind) or (Kind, OWN) (only the identity named in the key, or,
# for OWN_ROBOTS, an agent host for the robots it runs).
OWN: Final = "own"
OWN_ROBOTS: Final = "own robots"
Who = Kind | tuple[Kind, str]


@dataclass(frozen=True)
class KeyRoles:
    """Who writes a key (publishes samples, or declares the token) and who reads it (subscribes,
    or watches the token). Operators and observers read every key of the fleet in addition."""

    writers: tuple[Who, ...]
    readers: tuple[Who, ...] = ()
    token: bool = False  # a liveliness token key (TOKEN/WATCH instead of PUBLISH/READ)
    answerers: tuple[Kind, ...] = ()  # hold a queryable on the key (durable state)
    askers: tuple[Kind, ...] = ()  # query it (a process that starts or resumes)


_R, _H, _C = Kind.ROBOT, Kind.HOST, Kind.COORDINATOR
_L, _P, _O = Kind.LOCALIZATION, Kind.PLANT, Kind.OPERATOR

KEY_ROLES: Final[dict[str, KeyRoles]] = {
    keys.LEADER: KeyRoles((_C,), (_P,)),  # the plant reads it in lockstep
    keys.SLOT: KeyRoles((_C,)),
    keys.SETPOINT: KeyRoles((_C,), ((_R, OWN),)),
    keys.SETPOINTS: KeyRoles((_C,), (_R, _H)),
    keys.ASSIGNMENT: KeyRoles((_C,), (_C,)),  # a standby follows the active one's
    keys.POSE: KeyRoles((_L, _P), (_R, _C)),  # robots: neighbours' poses (repulsion)
    keys.POSES: KeyRoles((_L, _P), (_R, _H, _C)),
    keys.TRUTH: KeyRoles((_P,)),
    keys.TRUTHS: KeyRoles((_P,)),
    keys.WHEELS: KeyRoles(((_R, OWN),), (_P,)),
    # robots and hosts: the others' modes (cooperative neighbours, robot_agent.neighbours)
    keys.STATUS: KeyRoles(((_R, OWN),), (_C, _R, _H)),
    keys.HOST_WHEELS: KeyRoles(((_H, OWN),), (_P,)),
    keys.HOST_STATUS: KeyRoles(((_H, OWN),), (_C, _R, _H)),
    # the latched e-stop state: coordinators answer queries (robot_agent.estop, docs/faults.md);
    # agents and hosts ask when they start or resume, coordinators when they start, the
    # operator's tool to report who holds it
    keys.ESTOP: KeyRoles((_O,), (_R, _H, _C), answerers=(_C,), askers=(_R, _H, _C, _O)),
    keys.CLOCK: KeyRoles((_P,), (_R, _H, _C)),
    keys.DISTURBANCE: KeyRoles((_O,), (_P,)),
    keys.HEARTBEAT: KeyRoles(((_C, OWN),), (_C,)),
    keys.COORDINATOR_STATUS: KeyRoles(((_C, OWN),), (_C,)),
    keys.PLANT_STATUS: KeyRoles((_P,)),
    keys.ALIVE_ROBOT: KeyRoles(((_R, OWN), (_H, OWN_ROBOTS)), (_C, _P), token=True),
    keys.ALIVE_COORDINATOR: KeyRoles(((_C, OWN),), (_C, _P), token=True),
    keys.ALIVE_PLANT: KeyRoles((_P,), (_C,), token=True),
}
"""The publisher/reader roles of every key template (docs/security.md renders the same)."""

_missing = set(keys.KEY_TEMPLATES) ^ set(KEY_ROLES)
if _missing:  # a key added to the contract must say who may use it
    raise RuntimeError(f"bus_schemas.acl.KEY_ROLES and keys.KEY_TEMPLATES differ: {_missing}")


def _fill(template: str, fleet: str, *, robot: str = "*", name: str = "*") -> str:
    return template.format(fleet=fleet, robot=robot, name=name, slot="*")


def _matches(who: Who, ident: Identity) -> bool:
    return (who if isinstance(who, Kind) else who[0]) is ident.kind


def grants(ident: Identity, fleet: str = keys.DEFAULT_FLEET) -> tuple[tuple[Access, str], ...]:
    """Every (access, key expression) ``ident`` is allowed, from :data:`KEY_ROLES`."""
    keys.check_fleet(fleet)
    out: list[tuple[Access, str]] = []

    def add(access: Access, key: str) -> None:
        if (access, key) not in out:
            out.append((access, key))

    for leaf, roles in KEY_ROLES.items():
        template = keys.KEY_TEMPLATES[leaf]
        write, read = (Access.TOKEN, Access.WATCH) if roles.token else (Access.PUBLISH, Access.READ)
        for who in roles.writers:
            if not _matches(who, ident):
                continue
            if isinstance(who, Kind):
                add(write, _fill(template, fleet))
            elif who[1] == OWN_ROBOTS:
                for r in ident.robots:
                    add(write, _fill(template, fleet, robot=r))
            else:
                add(write, _fill(template, fleet, robot=ident.name, name=ident.name))
        for who in roles.readers:
            if not _matches(who, ident):
                continue
            if isinstance(who, Kind):
                add(read, _fill(template, fleet))
            else:
                add(read, _fill(template, fleet, robot=ident.name, name=ident.name))
        template_all = _fill(template, fleet)
        if ident.kind in roles.answerers:
            add(Access.ANSWER, template_all)
        if ident.kind in roles.askers:
            add(Access.ASK, template_all)
    if ident.kind in _READ_ALL:
        add(Access.READ, keys.fleet_pattern(fleet))
        add(Access.WATCH, keys.alive_pattern(fleet))
    return tuple(out)


# --- access_control ---------------------------------------------------------------------------


def _rule_id(ident: Identity, access: Access, flow: str) -> str:
    return f"{ident.cn}/{access}/{flow}"


def access_control(
    identities: Sequence[Identity], fleet: str = keys.DEFAULT_FLEET
) -> dict[str, Any]:
    """The router's ``access_control`` section: default deny, one subject per identity (its CN),
    one allow rule per (access, flow) with the identity's key expressions, one policy each."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    seen: set[str] = set()
    for ident in identities:
        if ident.cn in seen:
            raise ValueError(f"identity {ident.cn} given twice")
        seen.add(ident.cn)
        by_access: dict[Access, list[str]] = {}
        for access, key in grants(ident, fleet):
            by_access.setdefault(access, []).append(key)
        rule_ids: list[str] = []
        for access, key_exprs in by_access.items():
            for flow, messages in ZENOH_MESSAGES[access]:
                rid = _rule_id(ident, access, flow)
                rules.append(
                    {
                        "id": rid,
                        "permission": "allow",
                        "flows": [flow],
                        "messages": list(messages),
                        "key_exprs": list(key_exprs),
                    }
                )
                rule_ids.append(rid)
        if Access.PUBLISH in by_access:
            # A declared publisher sends only while it knows of a matching subscriber: let the
            # router tell it about every subscriber of the fleet, including wide ones such as a
            # recorder's formation/<fleet>/** (which no publish grant includes). Measured: with
            # the declarations limited to its own keys, r1's status publisher never sent to an
            # observer subscribed to formation/<fleet>/**. This reveals key expressions only.
            rid = _rule_id(ident, Access.PUBLISH, "discover")
            rules.append(
                {
                    "id": rid,
                    "permission": "allow",
                    "flows": ["egress"],
                    "messages": ["declare_subscriber"],
                    "key_exprs": [keys.fleet_pattern(fleet)],
                }
            )
            rule_ids.append(rid)
        subjects.append({"id": ident.cn, "cert_common_names": [ident.cn]})
        policies.append({"id": ident.cn, "rules": rule_ids, "subjects": [ident.cn]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def keyexpr_includes(pattern: str, key: str) -> bool:
    """True if the Zenoh key expression ``pattern`` (``*`` one chunk, ``**`` any number of
    chunks) includes the concrete ``key`` or the narrower pattern ``key``."""
    p, k = pattern.split("/"), key.split("/")

    def match(i: int, j: int) -> bool:
        if i == len(p):
            return j == len(k)
        if p[i] == "**":
            return any(match(i + 1, jj) for jj in range(j, len(k) + 1))
        if j == len(k) or k[j] == "**":
            return False
        return (p[i] == "*" or p[i] == k[j]) and match(i + 1, j + 1)

    return match(0, 0)


def is_allowed(acl: Mapping[str, Any], cn: str, flow: str, message: str, key: str) -> bool:
    """Evaluate an ``access_control`` section like the router does for the peer whose
    certificate CN is ``cn`` (default permission unless a rule matches; deny wins)."""
    subjects = {s["id"] for s in acl["subjects"] if cn in s.get("cert_common_names", ())}
    rules = {r["id"]: r for r in acl["rules"]}
    verdicts: set[str] = set()
    for policy in acl["policies"]:
        if not subjects.intersection(policy["subjects"]):
            continue
        for rid in policy["rules"]:
            rule = rules[rid]
            if (
                flow in rule["flows"]
                and message in rule["messages"]
                and any(keyexpr_includes(p, key) for p in rule["key_exprs"])
            ):
                verdicts.add(rule["permission"])
    if "deny" in verdicts:
        return False
    if "allow" in verdicts:
        return True
    return bool(acl["default_permission"] == "allow")


def may(acl: Mapping[str, Any], cn: str, access: Access, key: str) -> bool:
    """True if every Zenoh message that ``access`` needs on ``key`` is allowed for ``cn``."""
    return all(
        is_allowed(acl, cn, flow, message, key)
        for flow, messages in ZENOH_MESSAGES[access]
        for message in messages
    )


# --- whole configs ----------------------------------------------------------------------------

DEFAULT_PORT: Final = 7447
LEASE_MS: Final = 700
"""Transport lease of every deployed session: a hung or unplugged process is declared gone (its
liveliness token vanishes) within ~0.7 s; keep-alives every lease/4 (docs/deploy.md)."""
KEEP_ALIVES_PER_LEASE: Final = 4
MAX_MESSAGE_BYTES: Final = 128 * 1024
"""Largest Zenoh message a session reassembles (transport/link/rx/max_message_size): twice the
contract's largest payload (bus_schemas.MAX_PAYLOAD_BYTES), so a flood of huge messages cannot
grow a receiver (Zenoh's default is 1 GiB)."""


@dataclass(frozen=True)
class TlsFiles:
    """Paths of one identity's PEM files (as seen by the process that uses them)."""

    ca: str
    cert: str
    key: str


def _common(lease_ms: int) -> dict[str, Any]:
    return {
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "link": {
                "protocols": ["tls"],
                "tx": {"lease": lease_ms, "keep_alive": KEEP_ALIVES_PER_LEASE},
                "rx": {"max_message_size": MAX_MESSAGE_BYTES},
            }
        },
    }


def router_config(
    identities: Sequence[Identity],
    tls: TlsFiles,
    *,
    fleet: str = keys.DEFAULT_FLEET,
    listen: Sequence[str] = (f"tls/0.0.0.0:{DEFAULT_PORT}",),
    lease_ms: int = LEASE_MS,
) -> dict[str, Any]:
    """The fleet router's Zenoh config: TLS only with client certificates required (mTLS),
    multicast and gossip off, short lease, message size cap, admin space off, and the access
    control of ``identities``."""
    conf = _common(lease_ms)
    conf["mode"] = "router"
    conf["listen"] = {"endpoints": list(listen)}
    conf["adminspace"] = {"enabled": False}
    conf["transport"]["link"]["tls"] = {
        "root_ca_certificate": tls.ca,
        "listen_private_key": tls.key,
        "listen_certificate": tls.cert,
        "enable_mtls": True,
        "close_link_on_expiration": True,
    }
    conf["access_control"] = access_control(identities, fleet)
    return {k: conf[k] for k in ("mode", "listen", "scouting", "adminspace", "transport")} | {
        "access_control": conf["access_control"]
    }


def client_config(
    tls: TlsFiles,
    *,
    connect: Sequence[str] = (f"tls/localhost:{DEFAULT_PORT}",),
    lease_ms: int = LEASE_MS,
    retry_forever: bool = True,
) -> dict[str, Any]:
    """A process's Zenoh config: client of the fleet router over mTLS with its own certificate.

    ``retry_forever``: keep trying to reach the router (a robot may boot first); False makes
    ``zenoh.open`` fail at once when the router is absent (tests, local runs)."""
    conf = _common(lease_ms)
    conf["transport"]["link"]["tls"] = {
        "root_ca_certificate": tls.ca,
        "connect_private_key": tls.key,
        "connect_certificate": tls.cert,
        "enable_mtls": True,  # present the certificate above
        "verify_name_on_connect": True,  # the router's certificate must name its host
        "close_link_on_expiration": True,
    }
    connect_conf: dict[str, Any] = {"endpoints": list(connect)}
    if retry_forever:
        connect_conf |= {
            "timeout_ms": -1,
            "exit_on_failure": False,
            "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2},
        }
    else:
        connect_conf |= {"timeout_ms": 0, "exit_on_failure": True}
    return {"mode": "client", "connect": connect_conf} | conf


def _is_scalar(x: object) -> bool:
    return x is None or isinstance(x, str | int | float | bool)


def _dump(obj: Any, indent: int) -> str:
    """JSON with short scalar lists and small scalar maps on one line (readable ACLs)."""
    pad = " " * indent
    if isinstance(obj, Mapping):
        if not obj:
            return "{}"
        one_line = json.dumps(obj, separators=(", ", ": "))
        if all(_is_scalar(v) for v in obj.values()) and len(one_line) + indent < 90:
            return one_line
        inner = ",\n".join(
            f"{pad}  {json.dumps(k)}: {_dump(v, indent + 2)}" for k, v in obj.items()
        )
        return "{\n" + inner + "\n" + pad + "}"
    if isinstance(obj, list | tuple):
        one_line = json.dumps(list(obj), separators=(", ", ": "))
        if all(_is_scalar(v) for v in obj) and len(one_line) + indent < 90:
            return one_line
        inner = ",\n".join(f"{pad}  {_dump(v, indent + 2)}" for v in obj)
        return "[\n" + inner + "\n" + pad + "]"
    return json.dumps(obj)


def to_json5(conf: Mapping[str, Any], comment: str = "") -> str:
    """JSON5 text of a config (plain JSON, which is JSON5, behind ``//`` comment lines)."""
    head = "".join(f"// {line}".rstrip() + "\n" for line in comment.splitlines())
    return head + _dump(conf, 0) + "\n"


# --- deploy/zenoh -----------------------------------------------------------------------------

CERT_ROOT: Final = "/etc/formation/certs"
"""Where deployed hosts keep certificates: ``<CERT_ROOT>/<cn>/{ca,cert,key}.pem``."""
GENERATED: Final = (
    "Generated by `formation acl` (bus_schemas/acl.py) from the bus contract: do not edit."
)


def tls_files(cert_root: str | Path, cn: str) -> TlsFiles:
    """The PEM paths of identity ``cn`` under ``cert_root`` (the layout formation.pki writes)."""
    d = Path(cert_root) / cn
    return TlsFiles(ca=str(d / "ca.pem"), cert=str(d / "cert.pem"), key=str(d / "key.pem"))


def deploy_configs(
    identities: Sequence[Identity],
    *,
    fleet: str = keys.DEFAULT_FLEET,
    router_host: str = "coordinator.local",
    port: int = DEFAULT_PORT,
    cert_root: str = CERT_ROOT,
) -> dict[str, str]:
    """File name -> JSON5 text of the configs shipped in deploy/zenoh/.

    ``router-mtls.json5`` (the fleet router, ACL of every identity), then one client config per
    kind: ``robot-mtls.json5`` (a robot holds one identity: its files are directly in
    ``<cert_root>/``), ``coordinator-mtls.json5``, ``localization-mtls.json5``,
    ``operator-mtls.json5``, ``observer-mtls.json5`` (the coordinator host holds several: each
    reads its files from ``<cert_root>/<cn>/``, for the first identity of that kind), one
    ``coordinator-<name>-mtls.json5`` per coordinator instance, and ``client.json5`` (no TLS,
    for a trusted lab network only)."""
    names = ", ".join(i.cn for i in identities)
    router = router_config(
        identities, tls_files(cert_root, "router"), fleet=fleet, listen=(f"tls/0.0.0.0:{port}",)
    )
    out = {
        "router-mtls.json5": to_json5(
            router,
            f"{GENERATED}\nZenoh router of fleet {fleet!r} (`formation router --zenoh-config`):"
            " mTLS only, access control by\ncertificate common name (CN) for: "
            f"{textwrap.fill(names, 90)}.\nRegenerate after adding an identity: formation acl "
            "--out deploy/zenoh --robots ... --coordinators ...",
        )
    }
    connect = (f"tls/{router_host}:{port}",)
    per_kind = {
        "robot": f"a robot agent; its certificate (CN robot.<id>) and the CA are in {cert_root}/",
        "coordinator": "a coordinator instance",
        "localization": "the localization (camera tracker)",
        "operator": "the operator's tools (formation fault, e-stop)",
        "observer": "a read-only observer (formation top, record, dashboards)",
    }
    for kind, what in per_kind.items():
        matching = [i for i in identities if i.kind == kind]
        if not matching:
            continue
        if kind == "robot":
            root = Path(cert_root)
            files = TlsFiles(str(root / "ca.pem"), str(root / "cert.pem"), str(root / "key.pem"))
        else:
            files = tls_files(cert_root, matching[0].cn)
            what += f", certificate CN {matching[0].cn!r}"
        out[f"{kind}-mtls.json5"] = to_json5(
            client_config(files, connect=connect),
            f"{GENERATED}\nZenoh session of {what}:\nclient of the fleet router over mTLS. "
            f"Change {router_host!r} to the router host's name (it must be\nin the router "
            "certificate's subjectAltName: formation certs --router-host).",
        )
        if kind == "coordinator":
            # One file per instance (the active one and its standby run side by side on the
            # coordinator host, each with its own certificate): coordinator-<name>-mtls.json5,
            # read by formation-coordinator@<name>.service.
            for ident in matching:
                out[f"coordinator-{ident.name}-mtls.json5"] = to_json5(
                    client_config(tls_files(cert_root, ident.cn), connect=connect),
                    f"{GENERATED}\nZenoh session of coordinator instance {ident.name!r} "
                    f"(formation-coordinator@{ident.name}.service), certificate CN "
                    f"{ident.cn!r}:\nclient of the fleet router over mTLS. Change "
                    f"{router_host!r} to the router host's name (it must be\nin the router "
                    "certificate's subjectAltName: formation certs --router-host).",
                )
    plain: dict[str, Any] = {
        "mode": "client",
        "connect": {"endpoints": [f"tcp/{router_host}:{port}"]},
    }
    plain |= _common(LEASE_MS)
    plain["transport"]["link"]["protocols"] = ["tcp"]
    plain["connect"] |= {
        "timeout_ms": -1,
        "exit_on_failure": False,
        "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2},
    }
    out["client.json5"] = to_json5(
        plain,
        f"{GENERATED}\nZenoh session WITHOUT TLS: a trusted lab network only (anyone on the "
        "network can\npublish anything). For a fleet on a shared network use the *-mtls.json5 "
        "files.",
    )
    return out


def write_deploy_configs(
    out_dir: str | Path, identities: Sequence[Identity], **kw: Any
) -> list[Path]:
    """Write :func:`deploy_configs` into ``out_dir``; return the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in deploy_configs(identities, **kw).items():
        path = out / name
        path.write_text(text)
        written.append(path)
    return written


DEPLOY_ROBOTS: Final = ("r1", "r2", "r3")
DEPLOY_COORDINATORS: Final = ("main", "standby")


def deploy_identities(
    robots: Iterable[str] = DEPLOY_ROBOTS, coordinators: Iterable[str] = DEPLOY_COORDINATORS
) -> tuple[Identity, ...]:
    """The identities of the example fleet deploy/zenoh/ is generated for (``formation acl``'s
    defaults): robots r1-r3, coordinators main and standby, localization, operator, observer."""
    return fleet_identities(robots, coordinators)


# --- command line -----------------------------------------------------------------------------


def _csv(text: str) -> list[str]:
    return [p for p in (s.strip() for s in text.split(",")) if p]


def main(argv: list[str] | None = None) -> int:
    """``formation acl``: write the router's ACL and the client configs of a fleet."""
    parser = argparse.ArgumentParser(
        prog="formation acl",
        description="Write the Zenoh router config (mTLS + access control generated from the bus "
        "contract) and the client configs of a fleet.",
    )
    parser.add_argument("--out", required=True, help="directory to write the JSON5 files into")
    parser.add_argument("--fleet", default=keys.DEFAULT_FLEET)
    parser.add_argument("--robots", type=_csv, default=list(DEPLOY_ROBOTS), help="r1,r2,r3")
    parser.add_argument("--coordinators", type=_csv, default=list(DEPLOY_COORDINATORS))
    parser.add_argument("--operators", type=_csv, default=[""], help="operator names ('' = plain)")
    parser.add_argument("--observers", type=_csv, default=[""])
    parser.add_argument("--plant", action="store_true", help="allow a plant simulator identity")
    parser.add_argument("--router-host", default="coordinator.local")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT)
    parser.add_argument("--cert-root", default=CERT_ROOT)
    ns = parser.parse_args(argv)
    try:
        identities = fleet_identities(
            ns.robots,
            ns.coordinators,
            plant=ns.plant,
            operators=ns.operators or [""],
            observers=ns.observers or [""],
        )
        paths = write_deploy_configs(
            ns.out,
            identities,
            fleet=ns.fleet,
            router_host=ns.router_host,
            port=ns.port,
            cert_root=ns.cert_root,
        )
    except ValueError as exc:
        print(f"formation acl: {exc}", file=sys.stderr)
        return 2
    for p in paths:
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
