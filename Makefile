# Two commands for a newcomer: `make run` and `make test` (see README.md).
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed

.PHONY: run test bench clean

# One venv for both commands, with every extra (`.[dev]`: the suite exercises them all); it is rebuilt when
# pyproject.toml changes (the stamp is older than it).  pip runs with -qq: errors only, no notes of the build
# backend (setuptools describes every editable install whose package folders are mapped, as sim.examples is to
# models/).  Then every numba kernel is compiled once, for a generic CPU, into a cache folder inside the venv
# named by the kernel sources' content (hydraulics/kernel_cache.py), so that no run waits for a compiler.
# A user's own install: `pip install hydroplant`, then `hydroplant compile` (docs/own-machine.md).
$(STAMP): pyproject.toml
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install -qq --upgrade pip
	@echo "installing hydroplant and its dependencies into $(VENV) (a minute or two the first time)"
	$(VENV)/bin/python -m pip install -qq -e ".[dev]"
	@echo "compiling the kernels into $(VENV) (minutes of CPU, once per install; runs then load them)"
	$(VENV)/bin/hydroplant compile
	touch $(STAMP)

# The kernels were compiled at install: the run loads them and starts within seconds.  After an edit of a
# kernel source (a new cache key) the first run compiles its mode's kernels again, announced on stderr, unless
# `hydroplant compile` ran first; its reported wall time excludes the compilation.
run: $(STAMP)
	$(VENV)/bin/hydroplant run models/excavator/dig.scenario.toml

# `hydroplant compile` returns at once when the install's kernel cache still fits the sources; after an edit of a
# kernel source it compiles them again, two groups in parallel, before the suite runs on every core (pytest-xdist).
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
