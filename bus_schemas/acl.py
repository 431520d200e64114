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
operator ``<name>``    ``operator[.<name>]``        e-stop, disturbances, the virtual leader's
                                                    commands; the ROS 2 bridge's commands
                                                    (``/formation/cmd_vel``, ``goal``, services)
observer ``<name>``    ``observer[.<name>]``        nothing (recorder, dashboards, ``top``)
ROS 2 bridge           ``ros2[.<name>]``            its ROS topics and graph tokens (any domain
                                                    and namespace, bus_schemas.ros2.graph), and
                                                    the operator's e-stop, cmd_vel and goal
=====================  ===========================  ============================================

Each identity may read (subscribe to, and be delivered) what its process reads; the operator and
observers read the whole fleet. Zenoh checks ingress messages (from the identity to the router)
and egress messages (from the router to the identity) separately, so a grant is a pair:
publishing key K is ``put``/``delete`` ingress on K, reading K is ``declare_subscriber`` ingress
and ``put``/``delete`` egress on K; a liveliness token is ``liveliness_token`` ingress; watching
tokens is ``declare_liveliness_subscriber``/``liveliness_query`` ingress and ``liveliness_token``
egress; an identity that publishes is also told of every subscriber of the fleet
(``declare_subscriber`` egress on ``formation/<fleet>/**``), without which its declared publishers
do not send to wide subscribers such as a recorder's (tests/bus/test_acl.py checks each against a
real
router).
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from bus_schemas import keys
from bus_schemas.acl_rules import (  # noqa: F401  (moved to acl_rules.py; re-exported)
    _C,
    _H,
    _L,
    _NAMED,
    _O,
    _P,
    _R,
    _READ_ALL,
    CN_SEPARATOR,
    KEY_ROLES,
    OWN,
    OWN_ROBOTS,
    ZENOH_MESSAGES,
    Access,
    Identity,
    KeyRoles,
    Kind,
    Who,
    _fill,
    _matches,
    _missing,
    _rule_id,
    access_control,
    agent_host,
    coordinator,
    fleet_identities,
    grants,
    is_allowed,
    keyexpr_includes,
    may,
    robot,
)
from bus_schemas.session import DEFAULT_PORT, KEEP_ALIVES_PER_LEASE, LEASE_MS, MAX_MESSAGE_BYTES

# --- identities ------------------------------------------------------------------------------


# --- the role of every key -------------------------------------------------------------------


"""The publisher/reader roles of every key template (docs/security.md renders the same)."""

if _missing:  # a key added to the contract must say who may use it
    raise RuntimeError(f"bus_schemas.acl.KEY_ROLES and keys.KEY_TEMPLATES differ: {_missing}")


# --- access_control ---------------------------------------------------------------------------


# --- whole configs ----------------------------------------------------------------------------


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
    """The PEM paths of identity ``cn`` under ``cert_root`` (the layout of formation.launch.pki)."""
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
        "ros2": "the ROS 2 bridge (formation ros2, formation-ros2.service)",
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
    defaults): robots r1-r3, coordinators main and standby, localization, operator, observer,
    the ROS 2 bridge."""
    return fleet_identities(robots, coordinators, ros2=True)


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
    parser.add_argument(
        "--ros2",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the ROS 2 bridge's identity (CN ros2, `formation ros2`)",
    )
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
            ros2=ns.ros2,
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
