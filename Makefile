# The two commands of the README's quick start; each sets up .venv on first use.
VENV ?= .venv
PYTHON := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: install run test benchmark clean

$(STAMP): setup.py
	python3 -m venv $(VENV)
	$(PYTHON) -m pip install --quiet --upgrade pip
	$(PYTHON) -m pip install --quiet torch==2.13.0
	$(PYTHON) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

## run: the main job (scenario with reference policies, density 1; training lands with the learners)
run: $(STAMP)
	$(PYTHON) -m sb3_marl

## test: the whole test suite
test: $(STAMP)
	$(PYTHON) -m pytest -q

benchmark: $(STAMP)
	$(PYTHON) benchmarks/env_throughput.py

clean:
	rm -rf $(VENV) logs .pytest_cache
