# hypa: every target creates the virtual environment first if it is missing or stale.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
# test processes (pytest-xdist; a test file stays in one process, so its fixtures are built once):
# 2 suits CI's two cores; TEST_WORKERS=0 runs the suite in this process (a debugger, -x)
TEST_WORKERS ?= 2
PYTEST := $(BIN)/python -m pytest -q $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)
# mkdocs-material's banner about MkDocs 2.0 on every build (make docs, make test)
export NO_MKDOCS_2_WARNING := 1

.DEFAULT_GOAL := help
.PHONY: help install train evaluate reproduce simulate testbench tensorboard test test-slow test-all timing timing-fmu speed bench benchmark docs serve-docs lint clean

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-12s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	# torch first and pinned: an unpinned torch would pull several GB of CUDA packages
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP) ## create .venv and install hypa with its dependencies

train: $(STAMP) ## main job: the paper's V2 (LSTM) on the default data; more: ARGS="model=v1 ann=s4"
	$(BIN)/hypa train model=v2 ann=lstm $(ARGS)

evaluate: $(STAMP) ## evaluate a run: make evaluate ARGS="run=outputs/train/v2-lstm/<time>"
	$(BIN)/hypa evaluate $(ARGS)

reproduce: $(STAMP) ## train + evaluate every Table 1 row over 3 seeds -> results/REPORT.md
	$(BIN)/hypa reproduce $(ARGS)

simulate: $(STAMP) ## a physics model vs measured data: make simulate ARGS="dataset=silverbox model=silverbox_physical"
	$(BIN)/hypa simulate $(ARGS)

testbench: $(STAMP) ## generate (or find cached) test-bench data and print a summary
	$(BIN)/hypa testbench $(ARGS)

tensorboard: $(STAMP) ## open TensorBoard over all runs (outputs/ and multirun/)
	mkdir -p outputs multirun
	$(BIN)/tensorboard --logdir_spec runs:outputs,sweeps:multirun $(ARGS)

test: $(STAMP) ## ruff and the layers (the rules in pyproject.toml), the strict docs build, then the test suite without the slow checks (what CI runs)
	$(BIN)/ruff check hypa tests
	$(BIN)/lint-imports --no-cache
	$(BIN)/mkdocs build --strict --quiet
	$(PYTEST) $(ARGS)

lint: $(STAMP) ## ruff over hypa/ and tests/, and the layers' import contract (both in pyproject.toml)
	$(BIN)/ruff check hypa tests
	$(BIN)/lint-imports --no-cache

test-slow: $(STAMP) ## only the checks marked slow
	$(PYTEST) -m slow $(ARGS)

test-all: $(STAMP) ## every test
	$(PYTEST) -m "slow or not slow" $(ARGS)

timing: $(STAMP) ## how fast: the physics blocks (ratios) and the time to name causes; one part: ARGS="physics --min-time 0.1"
	$(BIN)/hypa timing $(ARGS)

timing-fmu: $(STAMP) ## an FMU block's speed (C loop against Python) on the tests' single-track FMU, built here with cc
	mkdir -p .cache && $(BIN)/python -c "import sys; sys.path.insert(0, 'tests'); from pathlib import Path; from fmu_fixtures import build_fmu; print(build_fmu('single_track', Path('$(CURDIR)/.cache/timing-fmu')))" > .cache/timing-fmu.path
	$(BIN)/hypa timing fmu --fmu "$$(cat .cache/timing-fmu.path)" --reference single_track $(ARGS)

speed bench: ## the former names of make timing (deprecated, go in the next release)
	@echo "make $@ is deprecated: use make timing" >&2
	@$(MAKE) --no-print-directory timing

benchmark: $(STAMP) ## real data (../shared/data): make benchmark ARGS="dataset=silverbox budget=full"
	$(BIN)/hypa benchmark $(ARGS)

docs: $(STAMP) ## the documentation site from docs/ and the docstrings: mkdocs build --strict -> site/
	$(BIN)/mkdocs build --strict

serve-docs: $(STAMP) ## serve the documentation at http://127.0.0.1:8000, rebuilt on every change
	$(BIN)/mkdocs serve

clean: ## remove run outputs (not the environment, not the data cache)
	rm -rf outputs multirun lightning_logs .pytest_cache
	@echo "(results/ of make reproduce kept)"
