"""``FleetRun``'s fault requests without a run: which robot names get the short ``--timeout``."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.testing import FleetRun


@pytest.mark.parametrize(
    ("args", "unknown"),
    [
        (("kill", "r9"), True),
        (("pause", "r9", "--at", "3"), True),
        (("estop", "r9"), True),
        (("kill", "r1"), False),
        (("release", "r3"), False),
        (("estop",), False),  # the fleet
        (("kill-leader",), False),
        (("kill-coordinator", "main"), False),  # a coordinator's name, not a robot
        (("estop", "--at", "3"), False),
    ],
)
def test_only_a_robot_the_run_lacks_is_looked_for_briefly(
    args: tuple[str, ...], unknown: bool, tmp_path: Path
) -> None:
    run = FleetRun("paper-exp1", workdir=tmp_path, lockstep=True)  # robots r1, r2, r3
    run._make_collector()
    assert run._unknown_robot(args) is unknown


def test_without_a_collector_every_robot_gets_the_full_timeout(tmp_path: Path) -> None:
    run = FleetRun("paper-exp1", workdir=tmp_path, lockstep=True)
    assert run._unknown_robot(("kill", "r9")) is False
