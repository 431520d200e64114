"""Zenoh routers of a test: :func:`launch_router` starts ``formation router`` on a free loopback
port (the ``router`` and ``start_router`` fixtures of tests/conftest.py use it) and
:func:`stop_router` stops one and checks it exited 0 within its bound."""

from __future__ import annotations

import signal
import subprocess
from dataclasses import dataclass

import pytest

from support.procguard import SIGTERM_PATIENCE_S
from support.spawn import Child, Spawner, free_port

ROUTER_READY = "router listening on "


@dataclass
class RouterHandle:
    """A running ``formation router`` subprocess."""

    endpoint: str  # e.g. "tcp/127.0.0.1:40123"
    port: int
    child: Child

    @property
    def proc(self) -> subprocess.Popen[bytes]:
        return self.child.proc


def launch_router(spawn: Spawner, *extra: str, attempts: int = 3) -> RouterHandle:
    """Start a router on a free port, retrying on the rare port race (another process took it)."""
    failure = ""
    for _ in range(attempts):
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        child = spawn("router", "--listen", endpoint, *extra)
        try:
            child.wait_for_line(ROUTER_READY)
        except AssertionError as exc:
            failure = str(exc)
            if child.proc.poll() is None:
                raise
            continue  # exited: most likely the port was taken meanwhile
        return RouterHandle(endpoint=endpoint, port=port, child=child)
    raise AssertionError(f"router did not start in {attempts} attempts: {failure}")


def stop_router(handle: RouterHandle) -> None:
    if handle.proc.poll() is not None:
        return  # a test stopped or killed it on purpose and checked what it wanted
    try:
        handle.child.stop(signal.SIGTERM, SIGTERM_PATIENCE_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"router ignored SIGTERM: {handle.child.describe()}", pytrace=False)
    assert handle.proc.returncode == 0, handle.child.describe()
