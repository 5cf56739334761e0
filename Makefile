# Two commands set everything up on a fresh machine: `make run` and `make test`.
# Both create .venv and install the project (editable, with its dev tools) when needed.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: run test lint format bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	@touch $(STAMP)

run: $(STAMP)
	INTSPACE_SIMULATION=$${INTSPACE_SIMULATION:-true} $(VENV)/bin/intspace serve

# Both cores: every test has its own files, ports and PostgreSQL database.
test: $(STAMP)
	$(PY) -m pytest -q -n 2

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

format: $(STAMP)
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

bench: $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev,bench]"
	@for b in bench/bench_*.py; do \
		echo "== $$b"; $(PY) -m bench.$$(basename $$b .py) || exit 1; \
	done

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache *.egg-info
