"""Network namespaces for the tests that run hosts on one machine (tests/fleet/test_multihost.py,
tests/fleet/test_deploy_netns.py): ``ip`` with its errors as assertion failures, and the teardown
that kills what still runs in a namespace and deletes it. A test that cannot make namespaces
(not root, no ``ip``, no permission) is skipped."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess

import pytest


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    """Run ``ip args...``; with ``check`` raise AssertionError with its stderr on failure."""
    proc = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)
    if check and proc.returncode != 0:
        raise AssertionError(f"ip {' '.join(args)}: status {proc.returncode}: {proc.stderr}")
    return proc


def skip_unless_root_with_ip() -> None:
    """Skip the test unless it runs as root with the ``ip`` command."""
    if os.geteuid() != 0:
        pytest.skip("needs root to create network namespaces and veth links")
    if shutil.which("ip") is None:
        pytest.skip("needs the `ip` command (iproute2)")


def add_namespace_or_skip(name: str) -> None:
    """``ip netns add name``; skip the test if that is not permitted here."""
    probe = ip("netns", "add", name, check=False)
    if probe.returncode != 0:
        pytest.skip(f"cannot create a network namespace: {probe.stderr.strip()}")


def netns_names() -> set[str]:
    out = ip("netns", "list", check=False).stdout
    return {line.split()[0] for line in out.splitlines() if line.strip()}


def delete_namespaces(names: list[str]) -> list[str]:
    """Kill what still runs in each namespace, delete it; return the problems found."""
    problems: list[str] = []
    for ns in names:
        pids = ip("netns", "pids", ns, check=False).stdout.split()
        for pid in pids:  # only processes this test started can be in its namespaces
            with contextlib.suppress(ProcessLookupError, ValueError):
                os.kill(int(pid), signal.SIGKILL)
        if pids:
            problems.append(f"namespace {ns} still had processes {pids} (killed)")
        ip("netns", "del", ns, check=False)
    left = netns_names().intersection(names)
    if left:
        problems.append(f"namespaces not deleted: {sorted(left)}")
    return problems
