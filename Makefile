# The two commands of the README: `make demo` (main job on the built-in synthetic scene) and `make test`.
.PHONY: setup demo test lint bench
PY := .venv/bin/python
DEMO_DIR ?= demo_project

setup:
	@bash scripts/bootstrap.sh

demo: setup
	$(PY) -m hybridsplat demo --out $(DEMO_DIR)

test: setup
	$(PY) -m pytest -q

lint: setup
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

bench: setup
	$(PY) bench/run_all.py
