# The two commands of README: `make demo` (set up, build, run the default scenario) and
# `make test` (set up, build, run ctest and pytest). Everything else is a step of those.
PYTHON ?= python3
VENV := .venv
BUILD := build
VENV_PYTHON := $(abspath $(VENV))/bin/python
JOBS ?= 2

.PHONY: setup build demo test clean fuzz fuzz-tools

# Reinstalled only when the dependency pins change.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV_PYTHON) -m pip install --quiet --upgrade pip
	$(VENV_PYTHON) -m pip install --quiet -e '.[test]'
	touch $@

# `make test` also needs torch (the 'train' extra: tests/test_forcenet_train.py trains a small network on the
# CPU); `make demo` does not: neither the FMUs nor the orchestrator use it.
$(VENV)/.installed-train: $(VENV)/.installed
	$(VENV_PYTHON) -m pip install --quiet -e '.[test,train]'
	touch $@

setup: $(VENV)/.installed

build: setup
	cmake -S . -B $(BUILD) -DPython3_EXECUTABLE=$(VENV_PYTHON) -DCMAKE_BUILD_TYPE=RelWithDebInfo
	cmake --build $(BUILD) -j $(JOBS)

# simulate -> align -> calibrate -> re-simulate -> report on the bundled UMich run, then the calibrated
# scenario (which applies the written parameter set by name) through the plain run command.
demo: build
	$(VENV_PYTHON) -m orchestrator run scenarios/umich_power.toml --fmu-dir $(BUILD)/fmus --out runs --no-progress
	$(VENV_PYTHON) -m orchestrator calibrate scenarios/calibration/umich_power.toml --fmu-dir $(BUILD)/fmus --out runs --no-progress
	$(VENV_PYTHON) -m orchestrator run scenarios/calibration/umich_power_calibrated.toml --fmu-dir $(BUILD)/fmus --out runs --no-progress

# clang for the short libFuzzer run of tests/test_interpolator_fuzz.py: installed when missing and we are root
# (CI); otherwise that run is skipped with its reason and the corpus replay in ctest still runs.
fuzz-tools:
	@command -v clang >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq clang >/dev/null) || \
	  echo "clang not installed: the short libFuzzer run is skipped (the corpus replay still runs)"; }

test: build $(VENV)/.installed-train fuzz-tools
	cd $(BUILD) && ctest --output-on-failure
	MILLING_TWIN_FMU_DIR=$(abspath $(BUILD))/fmus $(VENV_PYTHON) -m pytest

# libFuzzer on the interpolator's G-code parser and engine for FUZZ_TIME seconds (installs clang when
# missing; tests/fuzz/README.md). The committed corpus is replayed by ctest in every `make test`.
FUZZ_TIME ?= 600
fuzz: build
	sh tests/fuzz/run_fuzz.sh $(FUZZ_TIME)

clean:
	rm -rf $(BUILD) build-asan runs
