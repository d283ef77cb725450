# Two commands do all set-up on a fresh machine (see README):
#   make demo   create .venv, install flightgp, run `flightgp demo`
#   make test   create .venv, install flightgp with test extras, lint (ruff), run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: demo test test-fast clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip
	$(BIN)/python -m pip install -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/flightgp demo

# Lint first (ruff, configured in pyproject.toml), then two pytest workers on two cores, a test
# file at a time (--dist loadfile: a module's fixtures are made once, its contract class's tests
# included, which loadscope sends apart; a worker that finishes a file is sent the next one
# queued, so the long end-to-end modules do not leave one core idle): one BLAS thread each, or
# they fight over the cores.
test: $(STAMP)
	$(BIN)/ruff check gp_model validation fmu_src tests
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist loadfile $(PYTEST_ARGS)

# Local shortcut: skip the end-to-end tests marked slow.
test-fast: $(STAMP)
	$(BIN)/ruff check gp_model validation fmu_src tests
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MPLBACKEND=Agg $(BIN)/python -m pytest -n 2 --dist loadfile -m "not slow" $(PYTEST_ARGS)

clean:
	rm -rf $(VENV) build/* .pytest_cache
