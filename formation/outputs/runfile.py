"""The run file: how local tools find a running ``formation up`` and its credentials.

A ``formation up`` run registers itself in a per-user runtime directory
(``$XDG_RUNTIME_DIR/formation`` or ``/tmp/formation-<uid>``, mode 0700), keyed by the port of
its endpoint: ``<dir>/run-<port>.json`` with the endpoint, the fleet, the launcher's pid, the
output folder and, for an authenticated run (``--secure``), the Zenoh client configs of the
``operator`` and ``observer`` identities. ``formation fault``, ``top`` and ``record`` given no
``--zenoh-config`` look the endpoint's port up (:func:`tool_settings`) and, when a live run is
registered there, connect with its config: no extra typing, and only the same Unix user can
read the files (directory 0700, private keys 0600).

A file whose launcher is gone (SIGKILLed) is stale: :func:`lookup` ignores and removes it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import runtime as rt
from bus_schemas import keys

RUN_FILE_VERSION: Final = 1
_LOOPBACK: Final = ("127.0.0.1", "localhost", "::1", "[::1]", "0.0.0.0")


def runtime_dir() -> Path:
    """The per-user directory of run files and ephemeral PKIs (created 0700)."""
    base = os.environ.get("XDG_RUNTIME_DIR")
    path = (
        Path(base) / "formation"
        if base and os.path.isdir(base)
        else Path(tempfile.gettempdir()) / f"formation-{os.getuid()}"
    )
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.stat()
    if st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise PermissionError(f"{path} must be owned by this user with mode 0700")
    return path


def endpoint_port(endpoint: str) -> int | None:
    """The port of a loopback endpoint (``tcp/127.0.0.1:7447`` -> 7447); None for another
    host or a malformed endpoint."""
    _, _, addr = endpoint.partition("/")
    host, sep, port = addr.rpartition(":")
    if not sep or host not in _LOOPBACK:
        return None
    try:
        value = int(port.split("#", 1)[0])
    except ValueError:
        return None
    return value if 0 < value < 65536 else None


@dataclass(frozen=True)
class RunInfo:
    """A registered run (the JSON of its run file)."""

    endpoint: str
    port: int
    fleet: str
    pid: int
    out: str
    secure: bool
    configs: dict[str, str] = field(default_factory=dict)  # identity CN -> client config path
    children: dict[str, int] = field(default_factory=dict)  # node name -> pid

    def to_json(self) -> dict[str, Any]:
        return {
            "v": RUN_FILE_VERSION,
            "endpoint": self.endpoint,
            "port": self.port,
            "fleet": self.fleet,
            "pid": self.pid,
            "out": self.out,
            "secure": self.secure,
            "configs": dict(self.configs),
            "children": dict(self.children),
        }


def run_file(port: int) -> Path:
    return runtime_dir() / f"run-{port}.json"


def register(info: RunInfo) -> Path:
    """Write (atomically, mode 0600) the run file of ``info``; returns its path."""
    path = run_file(info.port)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        json.dump(info.to_json(), f, indent=1)
    os.replace(tmp, path)
    return path


def unregister(port: int, pid: int) -> None:
    """Remove the run file of ``port`` if it is the one of launcher ``pid``."""
    with contextlib.suppress(OSError, ValueError):
        path = run_file(port)
        data = json.loads(path.read_text())
        if data.get("pid") == pid:
            path.unlink()


def _is_launcher(pid: int) -> bool:
    try:
        args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return b"up" in args and any(a.endswith(b"formation") for a in args)


def lookup(port: int) -> RunInfo | None:
    """The live run registered on ``port``, or None (a stale file is removed)."""
    try:
        path = run_file(port)  # OSError (PermissionError) if the directory is not safe
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    try:
        info = RunInfo(
            endpoint=str(data["endpoint"]),
            port=int(data["port"]),
            fleet=str(data["fleet"]),
            pid=int(data["pid"]),
            out=str(data["out"]),
            secure=bool(data["secure"]),
            configs={str(k): str(v) for k, v in dict(data.get("configs", {})).items()},
            children={str(k): int(v) for k, v in dict(data.get("children", {})).items()},
        )
    except (KeyError, TypeError, ValueError):
        return None
    if not _is_launcher(info.pid):
        with contextlib.suppress(OSError):
            path.unlink()
        return None
    return info


ENDPOINT_ENV = "FORMATION_ENDPOINT"
FLEET_ENV = "FORMATION_FLEET"


def live_runs() -> list[RunInfo]:
    """Every live ``formation up`` registered on this host (stale files removed), by port."""
    try:
        names = sorted(runtime_dir().glob("run-*.json"))
    except OSError:
        return []
    out = []
    for path in names:
        port = path.stem.removeprefix("run-")
        if port.isdigit():
            info = lookup(int(port))
            if info is not None:
                out.append(info)
    return out


def resolve_target(ns: argparse.Namespace) -> str:
    """Fill a tool's endpoint and fleet when not given, and say where they came from.

    Endpoint (no ``--endpoint``/``--zenoh-config``): ``$FORMATION_ENDPOINT``, else the one live
    ``formation up`` on this host (its run file), else the default. Fleet (``--fleet`` not
    given, ``ns.fleet`` None): ``$FORMATION_FLEET``, else the fleet of the run registered on
    the endpoint's port, else the default. Returns "" or a note for the user."""
    note = ""
    if not getattr(ns, "zenoh_connect", None) and getattr(ns, "zenoh_config", None) is None:
        env = os.environ.get(ENDPOINT_ENV, "").strip()
        if env:
            ns.zenoh_connect = [env]
        else:
            runs = live_runs()
            if len(runs) == 1:
                ns.zenoh_connect = [runs[0].endpoint]
                note = f"the running `formation up` on {runs[0].endpoint}"
            elif runs:
                eps = ", ".join(f"{r.endpoint} (fleet {r.fleet})" for r in runs)
                note = (
                    f"several `formation up` runs on this host ({eps}): pass --endpoint or set "
                    f"{ENDPOINT_ENV}; trying the default {rt.DEFAULT_ENDPOINT}"
                )
    if hasattr(ns, "fleet") and ns.fleet is None:
        env = os.environ.get(FLEET_ENV, "").strip()
        port = endpoint_port(requested_endpoint(ns))
        info = lookup(port) if port is not None and not env else None
        ns.fleet = env or (info.fleet if info is not None else keys.DEFAULT_FLEET)
    return note


def requested_endpoint(ns: argparse.Namespace) -> str:
    """The endpoint a tool was pointed at (its first ``--endpoint``, else the default)."""
    connect = getattr(ns, "zenoh_connect", None)
    return str(connect[0]) if connect else rt.DEFAULT_ENDPOINT


def tool_settings(ns: argparse.Namespace, identity: str) -> rt.ZenohSettings:
    """Zenoh settings of a local tool (options of ``rt.add_zenoh_arguments``) acting as
    ``identity`` (``operator`` or ``observer``): with ``--zenoh-config`` exactly what was asked;
    otherwise, when an authenticated ``formation up`` is registered on the endpoint's port, its
    client config for ``identity`` (and its TLS endpoint); else the plain settings. The
    endpoint and fleet not given are found first (:func:`resolve_target`)."""
    resolve_target(ns)
    if getattr(ns, "zenoh_config", None) is None:
        port = endpoint_port(requested_endpoint(ns))
        info = lookup(port) if port is not None else None
        if info is not None and info.secure and identity in info.configs:
            return rt.ZenohSettings(
                connect=(),
                mode=None,
                config_file=info.configs[identity],
                lease_ms=ns.zenoh_lease_ms,
                namespace=ns.zenoh_namespace,
            )
    return rt.settings_from_args(ns)
