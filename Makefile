# The two set-up commands of the README: `make demo` and `make test`.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/nail2nail demo --out demo-output

test: $(STAMP)
	$(VENV)/bin/ruff check src tests bench
	$(PY) -m pytest src tests

bench: $(STAMP)
	$(PY) -m pip install -q -e ".[test,bench,icp]"
	$(PY) bench/run_all.py

clean:
	rm -rf $(VENV) demo-output .pytest_cache
