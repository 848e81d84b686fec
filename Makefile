# Two commands for a newcomer: `make run` and `make test` (see README.md).
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed

.PHONY: run test bench clean

# The venv is rebuilt when pyproject.toml changes (the stamp is older than it).
$(STAMP): pyproject.toml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/hydroplant run models/excavator/dig.scenario.toml

# The kernels are compiled first, two groups in parallel (sim/run/precompile.py; a warm cache only loads them),
# then the suite runs on every core (pytest-xdist).
test: $(STAMP)
	$(VENV)/bin/hydroplant compile
	$(VENV)/bin/python -m pytest -q -n auto

# Every benchmark in bench/; their figures rewrite docs/benchmarks.md (about an hour on 2 cores).
bench: $(STAMP)
	$(VENV)/bin/python bench/run_all.py

# Removes what the build made; the logs in logs/ are the user's and stay.
clean:
	rm -rf $(VENV) build *.egg-info
