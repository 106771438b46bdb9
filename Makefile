# rodo: two set-up commands for a new user (see README):
#   make demo   creates .venv, installs rodo with every extra, runs the main job end to end
#   make test   installs the same way and runs the whole test suite
# (`pip install rodo` alone is the core; the extras viz, icp, dask and all are in pyproject.toml)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.rodo-installed

.PHONY: demo test bench install clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@bash scripts/ensure_system_deps.sh
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[all,test]'
	$(BIN)/python -m rodo.warmup
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/rodo demo --out results/demo
	@echo "rodo is installed in $(VENV)/: run it as $(BIN)/rodo ..., or put it on PATH with: source $(BIN)/activate"

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python -m bench --out bench/RESULTS.md

clean:
	rm -rf $(VENV) results .hypothesis
