"""The pytest plugin of the formation package (entry point ``pytest11``: installed with the
package, nothing to configure; docs/api.md).

Fixture ``fleet``: a real fleet (:class:`formation.testing.FleetRun`) started for the test and
torn down after it, every process of it killed. The marker ``fleet`` says which::

    @pytest.mark.fleet("leader-kill", lockstep=True, duration_s=30)
    async def test_the_fleet_recovers(fleet):
        await fleet.wait_in_formation()
        await fleet.kill_leader()
        await fleet.finish()
        (kill,) = fleet.recovery()
        assert kill["recovered_s"] is not None

Marker arguments: the scenario (a built-in name or a TOML path), and ``lockstep``, ``hosts``,
``duration_s``, ``seed``, ``extra`` as :class:`FleetRun` takes them. The tests are coroutines
(pytest-asyncio; with ``asyncio_mode = "auto"`` nothing else is needed, otherwise mark them
``@pytest.mark.asyncio``).
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Any

import pytest

from formation.testing import FaultCommandError, FleetRun, FleetRunError

__all__ = ["FaultCommandError", "FleetRun", "FleetRunError", "fleet"]


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "fleet(scenario, *, lockstep=False, hosts=None, duration_s=None, seed=None, extra=()): "
        "the run the `fleet` fixture starts (formation.pytest_plugin)",
    )


try:  # the plugin loads in every pytest run of an environment with the package
    import pytest_asyncio

    _async_fixture: Any = pytest_asyncio.fixture
except ImportError:  # pragma: no cover (a user without pytest-asyncio: the fixture says so)
    _async_fixture = None


async def _fleet(request: pytest.FixtureRequest, tmp_path: Any) -> AsyncIterator[FleetRun]:
    """A started :class:`formation.testing.FleetRun` of the test's ``fleet`` marker."""
    marker = request.node.get_closest_marker("fleet")
    if marker is None or not marker.args:
        raise pytest.UsageError(
            "the `fleet` fixture needs @pytest.mark.fleet(SCENARIO, ...) on the test"
        )
    run = FleetRun(marker.args[0], workdir=tmp_path / "fleet", **marker.kwargs)
    try:
        await run.start()
        yield run
    finally:
        await run.close()


if _async_fixture is not None:
    fleet = _async_fixture(_fleet, name="fleet")
else:  # pragma: no cover

    @pytest.fixture(name="fleet")
    def fleet() -> None:
        raise pytest.UsageError(
            "the `fleet` fixture needs pytest-asyncio: pip install pytest-asyncio"
        )
