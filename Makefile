# l3 — two commands: `make demo` and `make test` set everything up themselves.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
L3     := $(VENV)/bin/l3
STAMP  := $(VENV)/.l3-installed
SHARED ?= ../shared/data
DEMO   ?= demo_out

.PHONY: setup demo test test-fast bench lint clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -n 2 -q

test-fast: $(STAMP)
	$(PY) -m pytest -n 2 -q -m "not slow"

lint: $(STAMP)
	$(VENV)/bin/ruff check l3cli tests benchmarks

demo: $(STAMP)
	bash scripts/demo.sh $(L3) $(DEMO)

bench: $(STAMP)
	$(PY) benchmarks/run_all.py --out docs/performance.md

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache .ruff_cache build *.egg-info
