# The two commands of the README: `make demo` (main job on the built-in synthetic scene) and `make test`.
.PHONY: setup demo test test-slow lint fuzz
PY := .venv/bin/python
DEMO_DIR ?= demo_project

setup:
	@bash scripts/bootstrap.sh

demo: setup
	$(PY) -m hybridsplat demo --out $(DEMO_DIR)

test: setup
	$(PY) -m pytest -q -m "not slow"

test-slow: setup
	$(PY) -m pytest -q -m slow

# Every malformed-input case through the CLI (subprocess, 60 s, 2 GB address space each) + properties.
fuzz: setup
	$(PY) -m pytest -q -m fuzz tests/fuzz

lint: setup
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
