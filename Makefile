# Every target that needs Python creates .venv and installs the project first,
# so `make run` or `make test` alone does all set-up on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test test-loaded test-docker bench lint typecheck clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/capataz run

test: $(STAMP)
	$(BIN)/python -m pytest -q

# the compose deployment on a real Docker engine (builds the image; BASE_IMAGE=... without Docker Hub)
test-docker: $(STAMP)
	CAPATAZ_DOCKER_TEST=1 $(BIN)/python -m pytest -q -s -m docker tests/integration/test_docker_e2e.py

# the suite on a host whose cores are all busy (busy-loop processes for the whole run)
test-loaded: $(STAMP)
	$(BIN)/python -m tests.under_load -q

bench: $(STAMP)
	$(BIN)/capataz bench all

lint: $(STAMP)
	$(BIN)/ruff check common services tests
	$(BIN)/ruff format --check common services tests

typecheck: $(STAMP)
	$(BIN)/mypy common services
	$(BIN)/mypy --strict common

clean:
	rm -rf out .pytest_cache .mypy_cache .ruff_cache
