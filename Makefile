# make demo / make test work on a fresh machine with only Python >= 3.10 (3.11 preferred):
# the first call creates .venv and installs the project into it.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-dev
BENCH_STAMP := $(VENV)/.installed-bench

.PHONY: demo test bench lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

$(BENCH_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[dev,bench]'
	touch $@

demo: $(STAMP)
	$(BIN)/crowdsim demo

# make test = the linter and the formatter check, then the suite (CI's .ci/run calls only this)
test: lint
	$(BIN)/python -m pytest -q -n 2

bench: $(BENCH_STAMP)
	$(BIN)/crowdsim bench sim

lint: $(STAMP)
	$(BIN)/ruff check crowdsim tracker envs synth_data tests benchmarks
	$(BIN)/ruff format --check crowdsim tracker envs synth_data tests benchmarks

clean:
	rm -rf $(VENV) build *.egg-info
