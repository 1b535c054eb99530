# horizon-nav: two commands on a fresh machine with Python 3.11 and make.
#   make demo   create .venv, install, run the main job on the default scenario
#   make test   create .venv if needed, install, run the whole suite
#   make bench  run tests/benchmarks and write bench.json (QUICK=1 for the short version)
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test bench clean install

install: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q tests --ignore=tests/benchmarks

demo: $(STAMP)
	$(BIN)/horizon-nav demo

bench: $(STAMP)
	HORIZON_NAV_BENCH_QUICK=$(QUICK) $(BIN)/python -m pytest -q -s tests/benchmarks -p no:cacheprovider

clean:
	rm -rf $(VENV) bench.json .pytest_cache
