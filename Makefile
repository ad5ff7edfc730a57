# The two set-up commands of the README: `make demo` (the main job) and `make test`.
# Both create the virtual environment on first use; torch is pinned to the local CPU build.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.kgnav-installed

# The main job: the with-memory ObjectNav benchmark, small by default (2 val houses x 15
# episodes, every variant, 2 processes: 8 minutes on 2 idle cores, about 20 on busy ones).
# Few houses and many episodes each give the memory something to reuse.
# `make demo FULL=1`: the whole val split (100 episodes a house).
VARIANTS ?= ans,hp,sp,si,sem+si,oracle
SCENES ?= 2
EPISODES ?= 15
WORKERS ?= 2
ifdef FULL
SIZE :=
else
SIZE := --scenes $(SCENES) --episodes $(EPISODES)
endif

.PHONY: demo test bench lint clean synthetic-demo

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/kgnav eval --split val --variants $(VARIANTS) $(SIZE) --workers $(WORKERS) --out export/eval

synthetic-demo: $(STAMP)
	$(VENV)/bin/kgnav demo --out export/demo --overwrite

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) bench/bench_graphml.py
	$(PY) bench/bench_relocator.py
	$(PY) bench/bench_sim.py
	$(PY) bench/bench_agent.py
	$(PY) bench/bench_encoder.py
	$(PY) bench/bench_segmenter.py
	$(PY) bench/bench_policy.py

lint: $(STAMP)
	$(VENV)/bin/ruff check kgnav tests queries bench

clean:
	rm -rf $(VENV) export/demo export/eval .pytest_cache .hypothesis
