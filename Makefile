# The two set-up commands of the README: `make demo` and `make test`.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean browser

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/nail2nail demo --out demo-output

# Debian's Chromium, for the tests that open the HTML report in a headless browser
# (tests/_browser.py skips them, with the reason, where it is absent). Installed when missing
# and apt-get is usable (root, or sudo without a password); never fails the target: one line
# says why it was not installed. ~13 s and 124 MB of packages on a Debian 12 machine.
CHROMIUM := /usr/bin/chromium
APT_CHROMIUM := env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium
browser:
	@if [ -x $(CHROMIUM) ]; then exit 0; fi; \
	if ! command -v apt-get >/dev/null 2>&1; then \
	  echo "browser: no apt-get here, $(CHROMIUM) not installed: the browser tests will skip"; exit 0; fi; \
	if [ "$$(id -u)" = 0 ]; then SUDO=; elif sudo -n true 2>/dev/null; then SUDO="sudo -n"; \
	else echo "browser: not root and no password-less sudo, $(CHROMIUM) not installed: the browser tests will skip"; exit 0; fi; \
	log=$$(mktemp); echo "browser: installing Debian's chromium with apt-get (for the report's browser test)"; \
	if $$SUDO $(APT_CHROMIUM) >$$log 2>&1 \
	   || { $$SUDO apt-get update -qq >>$$log 2>&1 && $$SUDO $(APT_CHROMIUM) >>$$log 2>&1; }; then rm -f $$log; \
	else echo "browser: apt-get install chromium failed (log: $$log): the browser tests will skip"; fi

# One process per core, at most 4 (each may hold a scale-0.5 demo in memory); a test file's
# tests stay on one process so that its module fixtures are built once. Plain `pytest` runs
# serially. Before the tests: ruff, the architecture contracts (import-linter, pyproject.toml
# [tool.importlinter]) and the type check (mypy, [tool.mypy]).
test: $(STAMP) browser
	$(VENV)/bin/ruff check src tests bench
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/mypy
	$(PY) -m pytest -n auto --maxprocesses 4 --dist loadfile src tests

bench: $(STAMP)
	$(PY) -m pip install -q -e ".[test,bench,icp]"
	$(PY) bench/run_all.py

clean:
	rm -rf $(VENV) demo-output .pytest_cache
