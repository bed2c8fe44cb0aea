# Every target that needs Python creates .venv and installs the project first,
# so `make run` or `make test` alone does all set-up on a fresh machine.
# `make run` needs the runtime dependencies only; tests, lint and type checks add the dev tools and the
# ros2 extra (rclpy and Fast DDS wheels for the bridge test: +161 MB, +16 s uncached, 3 s from uv's cache).
# pip installs uv into the venv, and uv installs the project: 3 s instead of pip's 26 s on 2 cores.
# PyPI has no tf2_msgs wheel: services/ros2/tf2_msgs_build.py generates and compiles it into the venv with the
# extra's rosidl generators and cc/c++ (for /tf_static; about 5 s, nothing when already built).
# Every install is constrained to deploy/constraints.txt (the tested versions); `make lock` renews it.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-runtime
DEV    := $(VENV)/.installed
PINS   := deploy/constraints.txt
UV     := $(BIN)/uv pip install --python $(BIN)/python --quiet --constraints $(PINS)

.PHONY: run test test-long test-loaded test-docker bench results lint typecheck clean lock

$(STAMP): pyproject.toml $(PINS)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --quiet --constraint $(PINS) 'uv>=0.5'
	$(UV) -e .
	touch $(STAMP)

$(DEV): $(STAMP) $(PINS) services/ros2/tf2_msgs_build.py
	$(UV) -e '.[dev,ros2]'
	$(BIN)/python -m services.ros2.tf2_msgs_build
	touch $(DEV)

run: $(STAMP)
	$(BIN)/capataz run

# two test processes, each module kept whole in one (its fixtures, its cluster); TEST_WORKERS=0: one process.
# Most of the suite waits on real clusters and flights at their frame rate, so two share two cores well.
# Three were faster on two cores (769 s against 982 s in a fresh clone) but starved the localizer of the
# whole-system test once (its pose/pf 0.19 m off, bound 0.10): kept at two until that holds under three.
TEST_WORKERS ?= 2
# the 25 slowest tests are listed at the end of every run: where the 15-minute aim is kept or lost
test: $(DEV)
	$(BIN)/python -m pytest -q --durations=25 $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

# the compose deployment on a real Docker engine (builds the image; BASE_IMAGE=... without Docker Hub)
test-docker: $(DEV)
	CAPATAZ_DOCKER_TEST=1 $(BIN)/python -m pytest -q -s -m docker tests/integration/test_docker_e2e.py

# the tests marked long (over a minute each, beside shorter tests that hold the same behaviour)
test-long: $(DEV)
	CAPATAZ_LONG_TESTS=1 $(BIN)/python -m pytest -q -m long

# the suite on a host whose cores are all busy (busy-loop processes for the whole run)
test-loaded: $(DEV)
	$(BIN)/python -m tests.under_load -q

bench: $(DEV)
	$(BIN)/capataz bench all

# docs/results.md and every marked figure of README.md and docs/*.md, from a fresh make run and every benchmark
# (long: the benchmarks take most of an hour on 2 cores); `capataz results` alone re-renders from out/
results: $(DEV)
	$(BIN)/capataz run
	$(BIN)/capataz bench all
	$(BIN)/capataz results

lint: $(DEV)
	$(BIN)/ruff check common services tests
	$(BIN)/ruff format --check common services tests

typecheck: $(DEV)
	$(BIN)/mypy common services
	$(BIN)/mypy --strict common

# the newest releases pyproject.toml's ranges admit, resolved in a scratch venv, become the pins (keeps the
# header); then `make test` before committing them
LOCK_VENV := out/lock-venv
lock:
	rm -rf $(LOCK_VENV) && $(PYTHON) -m venv $(LOCK_VENV)
	$(LOCK_VENV)/bin/python -m pip install --quiet --quiet 'uv>=0.5'
	$(LOCK_VENV)/bin/uv pip install --python $(LOCK_VENV)/bin/python --quiet -e '.[dev,ros2]'
	grep '^#' $(PINS) > $(PINS).new
	$(LOCK_VENV)/bin/uv pip freeze --python $(LOCK_VENV)/bin/python --exclude-editable \
		| grep -v -E '^(pip|setuptools)==' >> $(PINS).new
	mv $(PINS).new $(PINS) && rm -rf $(LOCK_VENV)

clean:
	rm -rf out .pytest_cache .mypy_cache .ruff_cache
