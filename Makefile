# Two commands on a fresh machine (Python 3.11+ and make): `make demo`, `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck bench clean venv accel

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[agent,sim,camera,dev]'
	@# the compiled firmware core (mypyc); without a C compiler the pure-Python core runs
	$(BIN)/python -m robot_agent.buildtools.accel build --quiet || echo "(the pure-Python firmware core runs)"
	@# the compiled simulator side (plant, camera, link, the in-process loop; sim_plant/core/_accel.py)
	@# and the coordinator's tick (coordinator/core/_accel.py)
	$(BIN)/python -m formation.sim.accel_build build --quiet || echo "(pure Python runs where not built)"
	touch $(STAMP)

# rebuild the compiled builds after an edit (firmware, simulator, coordinator; a stale one is unused)
accel: $(STAMP)
	$(BIN)/python -m robot_agent.buildtools.accel build
	$(BIN)/python -m formation.sim.accel_build build

demo: $(STAMP)
	$(BIN)/formation demo --out runs/demo

# Two parts (docs/testing.md). First, on two pytest-xdist workers, the in-process tiers (unit,
# repo, the docs' examples) together with the tier-2 tests (tests/bus, tests/fleet) marked
# shares_cpu: they assert no wall-clock bound, so they may run beside each other and beside the
# CPU-bound in-process tests, whose CPU time fills the fleets' waiting. Then the tier-2 tests
# marked alone (every other one: a latency, rate or exit-time bound, a realtime formation's
# quality, a CPU hog of its own) one at a time: their deadlines assume the fleet under test has
# the machine. Both parts run whatever the first one gives; the target fails if either failed.
test: $(STAMP)
	@rc=0; \
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=15 -m "not alone" tests docs/examples || rc=1; \
	$(BIN)/python -m pytest -q --durations=15 -m alone tests/bus tests/fleet || rc=1; \
	exit $$rc

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy coordinator robot_agent bus_schemas sim_plant formation runtime scenario localization

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) runs build *.egg-info robot_agent/_compiled sim_plant/_compiled coordinator/_compiled
