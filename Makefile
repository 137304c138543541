# Two commands: `make demo` and `make test`. Each creates .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# BLAS threads: bodymetry limits them itself at import (bodymetry/threads.py), so
# `make` and a plain shell run the same.

.PHONY: demo test lint bench bake clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# The person segmenter (capture/person.py) goes in without its declared dependencies
# (jax, non-headless OpenCV); its real needs are in pyproject.toml.
$(VENV)/.installed: $(BIN)/python pyproject.toml requirements-segmenter.txt
	$(BIN)/python -m pip install --quiet -e .
	$(BIN)/python -m pip install --quiet --no-deps -r requirements-segmenter.txt
	# numba compiles the kernels here, once, instead of in the first run (about 45 s).
	$(BIN)/bodymetry compile
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

# The main job: measure the person in the bundled demo recording (runs/demo/).
# --restart: a runs/demo left by an older bodymetry, or with other settings, is
# replaced (its own files only); a finished demo run with these settings is reused.
demo: $(VENV)/.installed
	$(BIN)/bodymetry process recordings/demo --out runs/demo --restart

# Two test processes, each test file whole in one of them (its module fixtures once):
# the suite takes about 4.5 minutes instead of 6.5 on the 2-core CI machine.
test: $(VENV)/.installed-test
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -n 2 --dist loadfile

bench: $(VENV)/.installed-test
	$(BIN)/python -m benchmarks

clean:
	rm -rf $(VENV) build *.egg-info
