# Two commands for a newcomer: `make run` and `make test` (see README.md).
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed

.PHONY: run test bench clean

# One venv for both commands, with every extra (`.[dev]`: the suite exercises them all); it is rebuilt when
# pyproject.toml changes (the stamp is older than it).  pip runs with -qq: errors only, no notes of the build
# backend (setuptools describes every editable install whose package folders are mapped, as sim.examples is to
# models/).  A user's own install needs only `pip install hydroplant` (docs/own-machine.md).
$(STAMP): pyproject.toml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install -qq --upgrade pip
	@echo "installing hydroplant and its dependencies into $(VENV) (a minute or two the first time)"
	$(VENV)/bin/python -m pip install -qq -e ".[dev]"
	touch $(STAMP)

# The first run compiles the kernels the scene uses (announced on stderr, minutes on a cold cache); later runs
# load them from numba's cache.  The reported wall time excludes the compilation.
run: $(STAMP)
	$(VENV)/bin/hydroplant run models/excavator/dig.scenario.toml

# The kernels are compiled first, two groups in parallel (sim/run/precompile.py; a warm cache only loads them),
# then the suite runs on every core (pytest-xdist).
test: $(STAMP)
	$(VENV)/bin/hydroplant compile
	$(VENV)/bin/python -m pytest -q -n auto

# Every benchmark in bench/; their figures rewrite docs/benchmarks.md and the figures of docs/figures/
# (about an hour on 2 cores).
bench: $(STAMP)
	$(VENV)/bin/python bench/run_all.py

# Removes what the build made; the logs in logs/ are the user's and stay.
clean:
	rm -rf $(VENV) build *.egg-info
