# The two commands of the README: `make demo` and `make test`. Each sets itself up first.
VENV ?= .venv
PY := $(VENV)/bin/python
export MUJOCO_GL ?= egl
export XLA_PYTHON_CLIENT_PREALLOCATE ?= false

.PHONY: setup demo test test-slow bench clean

setup:
	@VENV=$(VENV) ./scripts/setup.sh

demo: setup
	$(PY) -m rsrd_jax.cli demo --out demo_out

test: setup
	$(PY) -m pytest -q

test-slow: setup
	$(PY) -m pytest -q -m slow

bench: setup
	$(PY) -m benchmarks.run --json benchmarks/results/latest.json

clean:
	rm -rf demo_out .pytest_cache
