# Quick start: `make run` (build and query the main atlas), `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: run sphere view test lint bench clean

# Running needs the package alone; the tests add their extras (viser, selenium, mypy, the npm validator).
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(PY) -m pip install --quiet -e '.[test]'
	# The Khronos glTF Validator for the glTF tests (the npm registry; skipped without npm).
	if command -v npm >/dev/null 2>&1; then npm install --silent --no-audit --no-fund --prefix $(VENV)/node gltf-validator@2.0.0-dev.3.10; fi
	touch $@

# The main job: the demo human atlas (8 strategies), its report, sample
# queries and a reach motion. --resume keeps trees already built by an earlier run;
# prepare compiles what queries, motions and serve need (on a cold cache, once).
run: $(VENV)/.installed
	$(VENV)/bin/reach build configs/demo.yaml -o out/demo --resume
	$(VENV)/bin/reach prepare out/demo
	$(VENV)/bin/reach info out/demo
	$(VENV)/bin/reach report out/demo -o out/demo/report
	$(VENV)/bin/reach query out/demo 0.45 -0.25 1.20 --effector right_hand
	$(VENV)/bin/reach query out/demo 0.35 -0.15 0.05 --effector right_hand
	$(VENV)/bin/reach evaluate out/demo --targets configs/targets/workstation.csv
	$(VENV)/bin/reach motion out/demo 0.35 -0.15 0.05 --effector right_hand

# The interactive 3-D view of the demo atlas (built by `make run`), in the browser.
view: $(VENV)/.installed
	$(VENV)/bin/pip install --quiet -e '.[view]'
	$(VENV)/bin/reach build configs/demo.yaml -o out/demo --resume
	$(VENV)/bin/reach view out/demo

# The analytic example of the VATree core: a unit sphere.
sphere: $(VENV)/.installed
	$(VENV)/bin/reach build configs/sphere.yaml -o out/sphere
	$(VENV)/bin/reach info out/sphere
	$(VENV)/bin/reach query out/sphere 0.5 0.2 -0.3

# ruff (E501 at 120 characters among its rules), mypy, and the layers and cycles of the house (import-linter's
# contracts in pyproject.toml: tools -> serving -> motion -> answers -> build -> maps -> oracles, no cycles).
lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check reach oracles ros_bridge tests bench docs
	$(VENV)/bin/mypy
	$(VENV)/bin/lint-imports

test: lint
	$(PY) -m pytest -q

bench: $(VENV)/.installed-test
	$(PY) bench/config.py
	$(PY) bench/tree.py
	$(PY) bench/ik.py
	$(PY) bench/engine.py
	$(PY) bench/server.py
	$(PY) bench/build.py

clean:
	rm -rf $(VENV) out
