# gaitrig — two commands on a fresh machine: `make demo` and `make test`.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python

.PHONY: bootstrap demo test lint typecheck bench clean

bootstrap:
	@bash scripts/bootstrap.sh

demo: bootstrap
	$(VENV)/bin/gaitrig demo

# The suite runs as TEST_WORKERS processes, each taking whole test files (a file's fixtures
# are set up once): one per core, 1 to 4. TEST_WORKERS=0 runs it in this one process.
# The 30 slowest tests are listed at the end (the suite must stay under 15 minutes).
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); echo $$(( n < 1 ? 1 : (n > 4 ? 4 : n) )))

test: bootstrap
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder \
		--durations=30 $(PYTEST_ARGS)

lint: bootstrap
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy app engine

bench: bootstrap
	@set -e; for b in bench/[!_]*.py; do echo "# $$b" >&2; PYTHONPATH=$(CURDIR) $(PY) -P $$b; done

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache test-artifacts
