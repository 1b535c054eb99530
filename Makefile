# horizon-nav: two commands on a fresh machine with Python 3.11 and make.
#   make demo   create .venv, install, run the main job on the default scenario
#   make test   create .venv if needed, install, run the whole suite
#   make bench  run tests/benchmarks and write bench.json (QUICK=1 for the short version)
#   make view   open the demo's recording (logs/atek.rrd) in the pinned Rerun viewer
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test bench view clean install bytecode

install: $(STAMP)

# The package's modules byte-compiled (as pip does for a regular install; an editable one does
# not): where PYTHONDONTWRITEBYTECODE is set, every process otherwise compiled them from source
# at import, ~0.1-0.2 s of a replay's serial start. Up-to-date files are skipped.
bytecode: $(STAMP)
	@$(BIN)/python -m compileall -q nav vision scenarios

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

# The suite's files spread over JOBS processes (pytest-xdist; a file's tests stay together, so a
# module's fixtures are built once): the suite is one process's work per file, and CI has 2 cores.
JOBS ?= 2
test: $(STAMP) bytecode
	$(BIN)/python -m pytest -q tests --ignore=tests/benchmarks -n $(JOBS) --dist loadfile

demo: $(STAMP) bytecode
	$(BIN)/horizon-nav demo

view: $(STAMP)
	$(BIN)/rerun logs/atek.rrd

bench: $(STAMP) bytecode
	HORIZON_NAV_BENCH_QUICK=$(QUICK) $(BIN)/python -m pytest -q -s tests/benchmarks -p no:cacheprovider

clean:
	rm -rf $(VENV) bench.json .pytest_cache
