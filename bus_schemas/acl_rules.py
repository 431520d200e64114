"""Who may do what on the bus: the identities (``Identity``, their kinds and certificate CNs),
the role table :data:`KEY_ROLES` (for each key of the contract, who publishes, reads, declares
or watches it), the grants derived from it and the router's ``access_control`` section, plus
the checks ``is_allowed`` / ``may`` that tests and tools use. The table of identities and the
ingress/egress rules are described in ``acl.py``'s module docstring.

Split out of acl.py (issue 12) so acl.py reads as the generation of whole Zenoh configs (router,
clients, deploy/zenoh, ``formation acl``); every name here is still importable from
``bus_schemas.acl``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Final

from bus_schemas import keys


class Kind(StrEnum):
    """What an identity is; the first part of its certificate CN."""

    ROBOT = "robot"
    HOST = "host"
    COORDINATOR = "coordinator"
    LOCALIZATION = "localization"
    PLANT = "plant"
    OPERATOR = "operator"
    OBSERVER = "observer"
    ROS2 = "ros2"  # the ROS 2 bridge, `formation ros2` (bus_schemas.ros2.graph)


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
    ros2: bool = False,
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
    if ros2:
        out.append(Identity(Kind.ROS2))
    cns = [i.cn for i in out]
    if len(set(cns)) != len(cns):
        raise ValueError(f"duplicate identities: {sorted(c for c in cns if cns.count(c) > 1)}")
    return tuple(out)


class Access(StrEnum):
    """What an identity does with a key."""

    PUBLISH = "publish"  # put / delete samples
    READ = "read"  # subscribe and be delivered samples
    TOKEN = "token"  # declare a liveliness token
    WATCH = "watch"  # subscribe to / query liveliness tokens
    ANSWER = "answer"  # declare a queryable and reply to the queries it is sent
    ASK = "ask"  # query a key and be delivered the replies
    ASKED = "asked"  # be sent the queries on a key (one answering its own key under a wildcard)


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
    Access.ASKED: (("egress", ("query",)),),
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
    answerers: tuple[Who, ...] = ()  # hold a queryable on the key (durable state)
    askers: tuple[Kind, ...] = ()  # query it (a process that starts or resumes)


_R, _H, _C = Kind.ROBOT, Kind.HOST, Kind.COORDINATOR


_L, _P, _O = Kind.LOCALIZATION, Kind.PLANT, Kind.OPERATOR


_B = Kind.ROS2  # the ROS 2 bridge: reads the formation, forwards ROS commands to operator keys


KEY_ROLES: Final[dict[str, KeyRoles]] = {
    # the plant reads it in lockstep; a standby coordinator checks trajectory origins against it
    keys.LEADER: KeyRoles((_C,), (_P, _C, _B)),
    keys.SLOT: KeyRoles((_C,), (_B,)),
    keys.SETPOINT: KeyRoles((_C,), ((_R, OWN),)),
    keys.SETPOINTS: KeyRoles((_C,), (_R, _H)),
    keys.MOVERS: KeyRoles((_C,), (_R, _H)),  # issue 30: the robots' filters
    keys.ASSIGNMENT: KeyRoles((_C,), (_C,)),  # a standby follows the active one's
    keys.POSE: KeyRoles((_L, _P), (_R, _C, _B)),  # robots: neighbours' poses (repulsion)
    keys.POSES: KeyRoles((_L, _P), (_R, _H, _C, _B)),
    # the camera tracker's rendered source (`formation up --camera rendered`) renders the truth
    keys.TRUTH: KeyRoles((_P,), (_L,)),
    keys.TRUTHS: KeyRoles((_P,), (_L,)),
    keys.WHEELS: KeyRoles(((_R, OWN),), (_P,)),
    # robots and hosts: the others' modes (cooperative neighbours, robot_agent.core.neighbours)
    keys.STATUS: KeyRoles(((_R, OWN),), (_C, _R, _H, _B)),
    keys.HOST_WHEELS: KeyRoles(((_H, OWN),), (_P,)),
    keys.HOST_STATUS: KeyRoles(((_H, OWN),), (_C, _R, _H, _B)),
    # the latched e-stop state: coordinators answer queries (robot_agent.core.estop,
    # docs/faults.md);
    # agents and hosts ask when they start or resume, coordinators when they start, the
    # operator's tool to report who holds it
    # the ROS bridge's e-stop and release services take the operator's path (send_estop)
    keys.ESTOP: KeyRoles((_O, _B), (_R, _H, _C), answerers=(_C,), askers=(_R, _H, _C, _O, _B)),
    # the engagements an agent or agent host holds, each on its own key (only a coordinator's
    # answer on `estop` may carry a release record); asked by the same
    keys.ESTOP_HELD: KeyRoles((), answerers=((_R, OWN), (_H, OWN)), askers=(_R, _H, _C, _O, _B)),
    keys.CLOCK: KeyRoles((_P,), (_R, _H, _C)),
    keys.DISTURBANCE: KeyRoles((_O,), (_P,)),
    # scripted faults (bus_schemas.messages_fault): the active coordinator's notices, an
    # operator's requests (`formation fault ... --at T`); every node of the loop applies them
    keys.FAULT: KeyRoles((_C, _O), (_C, _P, _R, _H)),
    keys.HEARTBEAT: KeyRoles(((_C, OWN),), (_C,)),
    keys.COORDINATOR_STATUS: KeyRoles(((_C, OWN),), (_C, _B)),
    keys.PLANT_STATUS: KeyRoles((_P,)),
    # the camera tracker's health (`formation camera`, localization/node/camera.py): tools read it
    keys.CAMERA_STATUS: KeyRoles((_L,)),
    keys.ALIVE_ROBOT: KeyRoles(((_R, OWN), (_H, OWN_ROBOTS)), (_C, _P), token=True),
    keys.ALIVE_COORDINATOR: KeyRoles(((_C, OWN),), (_C, _P), token=True),
    keys.ALIVE_PLANT: KeyRoles((_P,), (_C,), token=True),
    # the operator drives the virtual leader (issue 28); every coordinator instance reads them
    # (a standby keeps them to continue after a takeover); the ROS bridge forwards
    # /formation/cmd_vel and /formation/goal into them (a ROS command takes the operator's path)
    keys.CMD_VEL: KeyRoles((_O, _B), (_C,)),
    keys.GOAL: KeyRoles((_O, _B), (_C,)),
    keys.PATH: KeyRoles((_O,), (_C,)),
    keys.SHAPE: KeyRoles((_O,), (_C,)),
    # a planning obstacle at run time (issue 27): the coordinators replan around it
    keys.OBSTACLE: KeyRoles((_O,), (_C,)),
}


_missing = set(keys.KEY_TEMPLATES) ^ set(KEY_ROLES)


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
        for who in roles.answerers:
            if not _matches(who, ident):
                continue
            if isinstance(who, Kind):
                add(Access.ANSWER, template_all)
            else:  # its own key only; the router hands it the queries of the wildcard key
                add(Access.ANSWER, _fill(template, fleet, name=ident.name))
                add(Access.ASKED, template_all)
        if ident.kind in roles.askers:
            add(Access.ASK, template_all)
    if ident.kind in _READ_ALL:
        add(Access.READ, keys.fleet_pattern(fleet))
        add(Access.WATCH, keys.alive_pattern(fleet))
    for access, key in _ros2_grants(ident.kind):
        add(access, key)
    return tuple(out)


def _ros2_grants(kind: Kind) -> list[tuple[Access, str]]:
    """The ROS 2 keys (rmw_zenoh's, outside ``formation/``; bus_schemas.ros2.graph): only the
    bridge publishes its topics, declares its tokens and serves its services; an operator
    publishes the topics it subscribes and calls its services (a ROS command reaches the fleet
    only through the bridge, which forwards it to the operator's keys); operators and observers
    read its topics and watch the ROS graph. No other identity may touch a ROS key."""
    from bus_schemas.ros2 import graph

    out: list[tuple[Access, str]] = []
    if kind is Kind.ROS2:
        out += [(Access.PUBLISH, k) for k in graph.published_keys()]
        out += [(Access.TOKEN, k) for k in graph.token_keys()]
        out += [(Access.READ, k) for k in graph.subscribed_keys()]
        out += [(Access.ANSWER, k) for k in graph.served_keys()]
    if kind is Kind.OPERATOR:
        out += [(Access.PUBLISH, k) for k in graph.subscribed_keys()]
        out += [(Access.ASK, k) for k in graph.served_keys()]
    if kind in _READ_ALL:
        out += [(Access.READ, k) for k in graph.published_keys()]
        out.append((Access.WATCH, graph.GRAPH_PATTERN))
    return out


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
            published = [k for k in by_access[Access.PUBLISH] if not k.startswith(keys.ROOT)]
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
                    "key_exprs": [keys.fleet_pattern(fleet), *published],
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
