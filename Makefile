# The two commands of the README's quick start; each sets up .venv on first use: `make run` with
# the runtime only (the package and its dependencies), `make test` adds the dev extra.
VENV ?= .venv
PYTHON := $(VENV)/bin/python
RUNTIME := $(VENV)/.installed-runtime
DEV := $(VENV)/.installed-dev

.PHONY: install run test benchmark clean

# PYTHONWARNINGS: setuptools' notice about editable installs (a UserWarning) is not printed
PIP := PYTHONWARNINGS=ignore::UserWarning $(PYTHON) -m pip install --quiet

$(RUNTIME): setup.py pyproject.toml
	python3 -m venv $(VENV)
	$(PIP) --upgrade pip
	$(PIP) torch==2.13.0
	$(PIP) -e .
	@echo "filling the compiled road kernel's cache once, both roads (the first command then starts at once)"
	$(VENV)/bin/sb3-marl baselines --eval-episodes 1 -o $(VENV)/compiled/baselines.md > /dev/null
	$(VENV)/bin/sb3-marl baselines --env sb3_marl/Merge-density1-v0 --eval-episodes 1 -o $(VENV)/compiled/baselines_merge.md > /dev/null
	touch $(RUNTIME)

$(DEV): $(RUNTIME)
	$(PIP) -e ".[dev]"
	touch $(DEV)

install: $(DEV)

## run: the main job: train MA2C on density 1 (short budget), evaluate it beside the reference
## policies; then the same for the safe recipe (-conf ma2c_safe); plot the learning curves;
## TensorBoard logs in logs/tensorboard
## (RUN_LOGS: the log folder, default logs; the tests point it at a temporary folder)
RUN_ENV ?= sb3_marl/LaneChange-density1-v0
RUN_TIMESTEPS ?= 100000
RUN_LOGS ?= logs
TRAIN := $(VENV)/bin/sb3-marl train --algo ma2c --env $(RUN_ENV) -n $(RUN_TIMESTEPS) --eval-freq 20000 --eval-episodes 6 --progress -f $(RUN_LOGS)
EVALUATE := $(VENV)/bin/sb3-marl evaluate --algo ma2c --env $(RUN_ENV) --eval-episodes 30 -f $(RUN_LOGS)
run: $(RUNTIME)
	$(TRAIN)
	$(EVALUATE) --with-baselines
	$(TRAIN) -conf ma2c_safe
	$(EVALUATE)
	$(VENV)/bin/sb3-marl plot --algo ma2c --env $(RUN_ENV) -f $(RUN_LOGS)

## test: lint (ruff), format check, types (mypy), then the whole test suite
test: $(DEV)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy sb3_marl wrappers sb3_marl_launcher.py
	$(PYTHON) -m pytest -q

benchmark: $(RUNTIME)
	$(PYTHON) benchmarks/env_throughput.py

clean:
	rm -rf $(VENV) logs .pytest_cache
