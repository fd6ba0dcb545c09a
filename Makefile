# Two entry points for a fresh machine (Python 3.11 + pip): `make demo` and `make test`.
# Both install into .venv with the exact versions the tests run on (constraints.txt).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
CONSTRAINTS := constraints.txt

.PHONY: demo test lint install wheel-check clean

$(STAMP): pyproject.toml $(CONSTRAINTS)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) -e ".[test,distributed,warp]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/jaxplan demo --out out/demo

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# Whole modules go to one worker (--dist loadscope), so a module's compiled fixtures are built once;
# the log ends with the 20 slowest tests.
test: lint
	$(PY) -m pytest -n 2 --dist loadscope -q --durations=20

# Build the wheel, install it (not editable) in a fresh virtual environment and run the rover and
# PushAround from outside the checkout: the wheel must carry everything they need.
wheel-check: $(STAMP)
	bash .ci/wheel_check.sh

clean:
	rm -rf $(VENV) out build dist
