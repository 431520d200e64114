# Two commands on a fresh machine (Python 3.11+ and make): `make demo`, `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck bench clean venv accel builds

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[agent,sim,camera,dev]'
	$(MAKE) --no-print-directory BUILD_FLAGS=--quiet builds
	touch $(STAMP)

# rebuild the compiled builds after an edit (firmware, simulator, coordinator; a stale one is unused)
accel: $(STAMP)
	$(MAKE) --no-print-directory builds

# The three compiled (mypyc) builds at once: the firmware core (robot_agent/core/_accel.py), the
# simulator side (plant, camera, link, the in-process loop; sim_plant/core/_accel.py) and the
# coordinator's tick (coordinator/core/_accel.py). Each is one gcc over one C file, compiled in
# its own temporary copy, checked against pure Python there and installed into its own folder, so
# they are independent: side by side they keep two cores busy (docs/testing.md, "Times"). A build
# that fails says why in one line and pure Python runs in its place (no C compiler: all three).
builds:
	@$(BIN)/python -m robot_agent.buildtools.accel build $(BUILD_FLAGS) \
	  || echo "(the pure-Python firmware core runs)" & \
	$(BIN)/python -m formation.sim.accel_build build --only simulator $(BUILD_FLAGS) \
	  || echo "(the pure-Python simulator runs)" & \
	$(BIN)/python -m formation.sim.accel_build build --only coordinator $(BUILD_FLAGS) \
	  || echo "(the pure-Python coordinator runs)" & \
	wait

demo: $(STAMP)
	$(BIN)/formation demo --out runs/demo

# Two parts (docs/testing.md). First, on two pytest-xdist workers, the in-process tiers (unit,
# repo, the docs' examples) together with the tier-2 tests (tests/bus, tests/fleet) marked
# shares_cpu: they assert no wall-clock bound, so they may run beside each other and beside the
# CPU-bound in-process tests, whose CPU time fills the fleets' waiting. Then the tier-2 tests
# marked alone (every other one: a latency, rate or exit-time bound, a realtime formation's
# quality, a CPU hog of its own) one at a time: their deadlines assume the fleet under test has
# the machine. Both parts run whatever the first one gives; the target fails if either failed.
# The project's own sources are byte-compiled first: an editable install leaves them as .py, and
# where PYTHONDONTWRITEBYTECODE is set (it is on some CI machines) every one of the suite's
# hundreds of fresh processes would compile them again in memory (about 0.1 CPU-s each);
# compileall skips what is current and Python ignores a .pyc whose source changed.
PACKAGES := coordinator robot_agent bus_schemas sim_plant formation runtime scenario localization

test: $(STAMP)
	@$(BIN)/python -m compileall -q -j 0 $(PACKAGES) > /dev/null || true
	@rc=0; \
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=15 -m "not alone" tests docs/examples || rc=1; \
	$(BIN)/python -m pytest -q --durations=15 -m alone tests/bus tests/fleet || rc=1; \
	exit $$rc

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy $(PACKAGES)

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) runs build *.egg-info robot_agent/_compiled sim_plant/_compiled coordinator/_compiled
