# magbench — run `make help` for the list of targets.
PYTHON ?= $(if $(wildcard .venv/bin/python),.venv/bin/python,python)
VENV ?= .venv
# The real recordings stay outside the repository (see docs/sweeps.md, "Real data").
MAGBENCH_DATA ?= $(if $(wildcard ../shared/data/real),$(abspath ../shared/data/real),)
export MAGBENCH_DATA

SWEEPS := baseline gamma beta K sigma coverage p0 wushi gyro real

SWEEP_TARGETS := $(addprefix sweep-,$(SWEEPS))

.PHONY: help install warmup test test-all lint bench reproduce $(SWEEP_TARGETS) report clean-parts

help: ## List the targets
	@grep -E '^[a-zA-Z_%-]+:.*## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*## "}; {printf "  %-16s %s\n", $$1, $$2}'

install: ## Create .venv and install magbench with its dev tools (the README's set-up)
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -e '.[dev]'

warmup: ## Compile the methods' numba kernels now (a first run does it itself, and says so)
	$(PYTHON) -m magbench warmup $(ARGS)

test: ## Run the test suite (what CI runs; slow tests excluded)
	$(PYTHON) -m pytest -q

test-all: ## Run every test, the slow ones too
	$(PYTHON) -m pytest -q -m ''

lint: ## ruff over the package and the tests
	$(PYTHON) -m ruff check src tests experiments

sweep-real: ## Every method on the real recordings in MAGBENCH_DATA (skipped when unset)
	@if [ -z "$(MAGBENCH_DATA)" ]; then \
	  echo "sweep real skipped: set MAGBENCH_DATA to a folder of recordings (see docs/sweeps.md, Real data)"; \
	else $(PYTHON) -m magbench sweep=real $(SWEEP_ARGS) $(ARGS); fi

# A static pattern rule: make never applies an implicit `sweep-%:` rule to .PHONY targets.
$(filter-out sweep-real,$(SWEEP_TARGETS)): sweep-%:
	$(PYTHON) -m magbench sweep=$* $(SWEEP_ARGS) $(ARGS)

sweep-NAME: ## Run one sweep, e.g. `make sweep-gamma` (extra overrides: ARGS="trials=20")
	@echo "use one of: $(SWEEP_TARGETS)"

# `make reproduce` runs every sweep (overwrite=true) in one process, so that the worker
# processes start and load the compiled loops once, and draws each figure once, in the report;
# rows whose sweep settings, method options and code are unchanged are reused, so it computes
# only what changed (ARGS="results_dir=/tmp/fresh" recomputes all into an empty folder). It
# prints the wall and CPU time of every step and writes them to
# results/bench/reproduce_times.csv (run it on a quiet machine for numbers worth quoting).
# The sweep-NAME targets above run one sweep each, as before.
reproduce: ## Every sweep at its committed size (what changed), then the report; times each step
	$(PYTHON) -m magbench reproduce $(ARGS)

bench: ## Time methods, peers, scaling, parallel speed-up, first run and reproduce (results/bench/)
	$(PYTHON) -m magbench bench $(ARGS)

report: ## Regenerate tables, figures and results/report.md from the CSV files
	$(PYTHON) -m magbench report $(ARGS)

clean-parts: ## Remove unfinished-sweep part files (finished results are kept)
	rm -rf results/*/parts
