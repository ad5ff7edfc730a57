# The two set-up commands of the README: `make demo` (the main job) and `make test`.
# Both create the virtual environment on first use; torch is pinned to the local CPU build.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.kgnav-installed

.PHONY: demo test bench lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/kgnav demo --out export/demo --overwrite

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) bench/bench_graphml.py
	$(PY) bench/bench_relocator.py
	$(PY) bench/bench_sim.py

lint: $(STAMP)
	$(VENV)/bin/ruff check kgnav tests queries bench

clean:
	rm -rf $(VENV) export/demo .pytest_cache .hypothesis
