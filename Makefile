# The two commands of README: `make demo` (set up, build, run the default scenario) and
# `make test` (set up, build, run ctest and pytest). Everything else is a step of those.
PYTHON ?= python3
VENV := .venv
BUILD := build
VENV_PYTHON := $(abspath $(VENV))/bin/python
JOBS ?= 2

.PHONY: setup build demo test clean

# Reinstalled only when the dependency pins change.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV_PYTHON) -m pip install --quiet --upgrade pip
	$(VENV_PYTHON) -m pip install --quiet -e '.[test]'
	touch $@

setup: $(VENV)/.installed

build: setup
	cmake -S . -B $(BUILD) -DPython3_EXECUTABLE=$(VENV_PYTHON) -DCMAKE_BUILD_TYPE=RelWithDebInfo
	cmake --build $(BUILD) -j $(JOBS)

demo: build
	$(VENV_PYTHON) -m orchestrator run scenarios/umich_power.toml --fmu-dir $(BUILD)/fmus --out runs

test: build
	cd $(BUILD) && ctest --output-on-failure
	MILLING_TWIN_FMU_DIR=$(abspath $(BUILD))/fmus $(VENV_PYTHON) -m pytest

clean:
	rm -rf $(BUILD) build-asan runs
