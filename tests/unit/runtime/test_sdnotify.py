"""runtime.sdnotify against a real AF_UNIX datagram socket standing in for systemd."""

from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.sdnotify import Notifier


@pytest.fixture
def receiver(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A bound datagram socket on a filesystem path, like systemd's notify socket."""
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(1.0)
    try:
        yield sock, path
    finally:
        sock.close()


def _recv(sock: socket.socket) -> str:
    return sock.recv(4096).decode()


def test_ready_watchdog_stopping_status_reach_the_socket(
    receiver: tuple[socket.socket, str],
) -> None:
    sock, path = receiver
    with Notifier({"NOTIFY_SOCKET": path}) as notifier:
        assert notifier.enabled
        assert notifier.ready(status="motors open")
        assert _recv(sock) == "READY=1\nSTATUS=motors open"
        assert notifier.watchdog()
        assert _recv(sock) == "WATCHDOG=1"
        assert notifier.status("tracking slot 2\nsecond line")
        assert _recv(sock) == "STATUS=tracking slot 2 second line"  # one line only
        assert notifier.stopping()
        assert _recv(sock) == "STOPPING=1"
        assert notifier.sent == 4
        assert notifier.errors == 0


def test_abstract_namespace_socket() -> None:
    name = f"formation-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name.encode())
    sock.settimeout(1.0)
    try:
        notifier = Notifier({"NOTIFY_SOCKET": "@" + name})
        assert notifier.ready()
        assert _recv(sock) == "READY=1"
        notifier.close()
    finally:
        sock.close()


def test_noop_without_notify_socket() -> None:
    notifier = Notifier({})
    assert not notifier.enabled
    assert notifier.ready() is False
    assert notifier.watchdog() is False
    assert notifier.status("x") is False
    assert notifier.sent == 0 and notifier.errors == 0
    assert notifier.watchdog_interval_s() is None


def test_vanished_socket_is_counted_not_raised(tmp_path: Path) -> None:
    notifier = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens.sock")})
    assert notifier.enabled
    assert notifier.watchdog() is False
    assert notifier.watchdog() is False
    assert notifier.errors == 2
    assert notifier.sent == 0


def test_reconnects_after_systemd_socket_comes_back(tmp_path: Path) -> None:
    path = str(tmp_path / "notify.sock")
    notifier = Notifier({"NOTIFY_SOCKET": path})
    assert notifier.watchdog() is False  # not there yet
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(1.0)
    try:
        assert notifier.watchdog() is True
        assert _recv(sock) == "WATCHDOG=1"
    finally:
        sock.close()
        notifier.close()


@pytest.mark.parametrize(
    ("env", "expected_interval_s"),
    [
        ({"WATCHDOG_USEC": "2000000"}, 1.0),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "4242"}, 1.0),  # pid matches
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}, None),  # meant for another pid
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "-5"}, None),
        ({"WATCHDOG_USEC": "two seconds"}, None),
        ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "x"}, None),
        ({}, None),
    ],
)
def test_watchdog_interval(env: dict[str, str], expected_interval_s: float | None) -> None:
    notifier = Notifier(env, pid=4242)
    assert notifier.watchdog_interval_s() == expected_interval_s
    if expected_interval_s is not None:
        assert notifier.watchdog_timeout_s() == 2 * expected_interval_s


def test_reads_process_environment_by_default(
    receiver: tuple[socket.socket, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    sock, path = receiver
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    monkeypatch.setenv("WATCHDOG_USEC", "500000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    notifier = Notifier()
    assert notifier.watchdog_interval_s() == 0.25
    assert notifier.watchdog()
    assert _recv(sock) == "WATCHDOG=1"
    notifier.close()


def test_relative_or_vsock_address_is_ignored() -> None:
    assert not Notifier({"NOTIFY_SOCKET": "relative/path"}).enabled
    assert not Notifier({"NOTIFY_SOCKET": "vsock:2:1234"}).enabled
