# Quick start: `make run` (build and query the main atlas), `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: run test lint bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

run: $(VENV)/.installed
	$(VENV)/bin/reach build configs/sphere.yaml -o out/sphere
	$(VENV)/bin/reach info out/sphere
	$(VENV)/bin/reach query out/sphere 0.5 0.2 -0.3
	$(VENV)/bin/reach query out/sphere 0.9 0.9 0.0

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check reach oracles tests bench

test: lint
	$(PY) -m pytest -q

bench: $(VENV)/.installed
	$(PY) bench/tree.py

clean:
	rm -rf $(VENV) out
