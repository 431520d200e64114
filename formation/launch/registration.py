"""A ``formation up`` run's entry in the run files (:mod:`formation.outputs.runfile`:
``run-<port>.json`` in the user's runtime directory), so ``formation fault``, ``top`` and
``record`` find the run, its children and (``--secure``) its credentials.
:class:`RunRegistration` writes it (again after a respawn: the pids changed) and removes it."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from formation.launch.plan import UpConfig

__all__ = ["RunRegistration"]


class RunRegistration:
    """The run file of one run (``out_dir``: the run's ``--out``)."""

    def __init__(self, cfg: UpConfig, out_dir: Path) -> None:
        self.cfg = cfg
        self.out_dir = out_dir
        self.port: int | None = None  # registered under this port

    def register(self, secure: Any, children: dict[str, int]) -> str | None:
        """Write (or rewrite) the run file; returns why it could not be written, or None.
        ``secure``: the run's :class:`formation.launch.pki.RunConfigs` or None; ``children``:
        name -> pid."""
        from formation.outputs import runfile

        port = runfile.endpoint_port(self.cfg.endpoint)
        if port is None:
            return None
        configs = {}
        if secure is not None:
            configs = {cn: str(secure.clients[cn]) for cn in ("operator", "observer")}
        info = runfile.RunInfo(
            endpoint=secure.endpoint if secure is not None else self.cfg.endpoint,
            port=port,
            fleet=self.cfg.fleet,
            pid=os.getpid(),
            out=str(self.out_dir.resolve()),
            secure=secure is not None,
            configs=configs,
            children=children,
        )
        try:
            runfile.register(info)
        except OSError as exc:
            return f"could not write the run file: {exc}"
        self.port = port
        return None

    def unregister(self) -> None:
        if self.port is not None:
            from formation.outputs import runfile

            runfile.unregister(self.port, os.getpid())
