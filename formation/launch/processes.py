"""The process table of a ``formation up`` run: which child runs as the router, which as the
nodes, which died and were replaced, and the process group they all share.

:class:`ProcessTable` is the one owner of the run's :class:`~formation.launch.children.Child`
objects: it spawns them (the router first, as the leader of a new process group every later
child joins, so a terminal's Ctrl-C reaches only the launcher), replaces a dead one by its
respawn, and answers who is running."""

from __future__ import annotations

import signal
from collections.abc import Mapping, Sequence
from pathlib import Path

from formation.launch.children import Child, child_env

__all__ = ["ProcessTable"]


class ProcessTable:
    """The run's children, their logs in ``log_dir``; ``env``: variables every child gets unless
    the user's environment sets them (children.child_env)."""

    def __init__(self, log_dir: Path, env: Mapping[str, str] | None = None) -> None:
        self.log_dir = log_dir
        self.env = dict(env or {})
        self.router: Child | None = None
        self.nodes: list[Child] = []
        self.retired: list[Child] = []  # dead children replaced by a respawn
        self.group: int | None = None  # process group of every child (the first router's pid)

    async def start_router(self, args: Sequence[str]) -> Child:
        """Spawn the router as the leader of the run's new process group."""
        router = Child("router", args, "router listening on ", self.log_dir)
        await router.spawn(child_env(self.env), process_group=0)
        assert router.pid is not None
        self.router, self.group = router, router.pid
        return router

    async def start_node(self, name: str, args: Sequence[str], ready: str) -> Child:
        """Spawn a node into the run's group (after :meth:`start_router`)."""
        assert self.group is not None
        child = Child(name, args, ready, self.log_dir)
        self.nodes.append(child)
        await child.spawn(child_env(self.env), process_group=self.group)
        return child

    async def replace(self, old: Child, args: Sequence[str]) -> Child:
        """Spawn ``old``'s next generation with ``args`` and put it in ``old``'s place (``old``
        is retired: its logs and times stay in the run's record)."""
        assert self.group is not None
        child = Child(old.name, args, old.ready_prefix, self.log_dir, generation=old.generation + 1)
        # fork+exec of a fresh interpreter: the child never runs this process's Zenoh state
        # (the fork hazard of the field notes is a forked child *using* it); it joins the run's
        # process group (which outlives its first leader, the first router, while any member
        # lives).
        await child.spawn(child_env(self.env), process_group=self.group)
        self.retired.append(old)
        if old is self.router:
            self.router = child
        else:
            self.nodes[self.nodes.index(old)] = child
        return child

    def current(self) -> list[Child]:
        """The nodes and the router now (running or not, without the retired ones)."""
        return [*self.nodes, *([self.router] if self.router is not None else [])]

    def every(self) -> list[Child]:
        """Every child the run started, the retired ones first."""
        return [*self.retired, *self.current()]

    def agents(self) -> list[Child]:
        return [c for c in self.nodes if c.name.startswith("agent-")]

    def pids(self) -> dict[str, int]:
        """Name -> pid of the current children (the run file's ``children``)."""
        return {c.name: c.pid for c in self.current() if c.pid is not None}

    def another_running(self, child: Child, prefix: str) -> bool:
        """Whether a node other than ``child`` whose name starts with ``prefix`` still runs."""
        return any(
            c is not child and c.name.startswith(prefix) and c.returncode is None
            for c in self.nodes
        )

    def kill_all(self) -> None:
        """SIGKILL every child the run started (a second stop signal)."""
        for child in self.every():
            child.signal(signal.SIGKILL)
