"""The Zenoh session settings the contract fixes, declared once: every process, tool and deploy
config reads them from here (``runtime.transport`` for live sessions, ``bus_schemas.acl`` for the
generated deploy configs, ``formation up`` for its nodes).

Standard library only (a robot imports it).
"""

from __future__ import annotations

from typing import Final

from bus_schemas.fields import MAX_PAYLOAD_BYTES

__all__ = [
    "DEFAULT_ENDPOINT",
    "DEFAULT_PORT",
    "KEEP_ALIVES_PER_LEASE",
    "LEASE_MS",
    "MAX_MESSAGE_BYTES",
]

DEFAULT_PORT: Final = 7447
DEFAULT_ENDPOINT: Final = f"tcp/127.0.0.1:{DEFAULT_PORT}"
"""Where ``formation up`` / ``formation router`` listen and every tool connects by default."""

LEASE_MS: Final = 700
"""Zenoh transport lease of every session (deployed and ``formation up``): a hung (SIGSTOPped)
or unplugged process is declared gone (its liveliness token vanishes) within ~0.7 s, inside the
1 s the fault tests allow; keep-alives every lease / :data:`KEEP_ALIVES_PER_LEASE`, sent by
Zenoh's own threads (docs/deploy.md, docs/faults.md)."""

KEEP_ALIVES_PER_LEASE: Final = 4
"""Keep-alive messages per lease period (Zenoh's own default ratio, written explicitly so a short
lease always comes with a proportionally short keep-alive interval)."""

MAX_MESSAGE_BYTES: Final = 2 * MAX_PAYLOAD_BYTES
"""Largest Zenoh message any session reassembles (``transport/link/rx/max_message_size``): twice
the contract's largest payload (64 KiB; bigger ones are rejected by decode anyway). Zenoh's
default is 1 GiB: a flood of large messages grew every receiver by ~20 MiB per burst."""
