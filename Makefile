# The two commands of README: `make demo` (set up, build, run the whole-part twins) and
# `make test` (set up, build, run ctest and pytest). Everything else is a step of those.
PYTHON ?= python3
VENV := .venv
BUILD := build
VENV_PYTHON := $(abspath $(VENV))/bin/python
JOBS ?= 2
# pytest's tests spread over JOBS processes (pytest-xdist): the suite is CPU-bound, so on the 2 cores of CI this
# halves its time. `pytest tests/x.py` by hand stays one process. PYTEST_PARALLEL= runs `make test` serially.
# loadgroup: tests marked with one xdist_group run on one worker (the libFuzzer runs and the sanitizer tests, each
# group building one folder).
PYTEST_PARALLEL ?= -n $(JOBS) --dist loadgroup

.PHONY: setup configure fmus build demo test test-sanitize clean fuzz test-tools wheel release

# Reinstalled only when the dependencies change: pyproject.toml's ranges, installed at constraints.txt's exact versions
# (the same set on every machine and in CI; docs/packaging.md).
$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(VENV_PYTHON) -m pip install --quiet --upgrade pip
	$(VENV_PYTHON) -m pip install --quiet -c constraints.txt -e '.[test]'
	touch $@

# `make test` also needs torch (the 'train' extra: tests/test_forcenet_train.py trains a small network on the
# CPU); `make demo` does not: neither the FMUs nor the orchestrator use it.
# torch from PyPI is the CUDA wheel with its libraries: ~3 GB downloaded, ~5.5 GB installed. Without pip's wheel
# cache (--no-cache-dir) a fresh machine needs the download once, not twice. Short free space is named before pip
# starts (a warning, not a refusal: the estimate is rough), so an ENOSPC halfway through explains itself.
TRAIN_FREE_GB := 9
$(VENV)/.installed-train: $(VENV)/.installed
	@free_kb=$$(df -Pk . 2>/dev/null | awk 'NR==2 {print $$4}'); \
	  if [ -n "$$free_kb" ] && [ "$$free_kb" -lt $$(( $(TRAIN_FREE_GB) * 1024 * 1024 )) ]; then \
	    echo "make test installs torch (the 'train' extra), which needs about $(TRAIN_FREE_GB) GB free;" \
	         "$$(( free_kb / 1024 / 1024 )) GB are free here. If pip fails with 'No space left', free some." >&2; \
	  fi
	$(VENV_PYTHON) -m pip install --quiet --no-cache-dir -c constraints.txt -e '.[test,train]'
	touch $@

setup: $(VENV)/.installed

configure: setup
	cmake -S . -B $(BUILD) -DPython3_EXECUTABLE=$(VENV_PYTHON) -DCMAKE_BUILD_TYPE=RelWithDebInfo

# What an importer loads and the orchestrator runs: every FMU (FMI 2 and 3) and the stepper library.
fmus: configure
	cmake --build $(BUILD) -j $(JOBS) --target fmu_binaries

# Every FMU (FMI 2 and 3) and the stepper library for Linux x86_64/aarch64 (glibc 2.17), Windows x86_64 and macOS
# x86_64/arm64, cross-compiled from build/fmus' sources/ with zig's cc into build/fmus-all/ (docs/portability.md);
# build/fmus/ stays as it is. zig: the `ziglang` package of the test extra.
.PHONY: fmus-all-platforms
fmus-all-platforms: fmus
	@$(VENV_PYTHON) -c 'import ziglang' 2>/dev/null || $(VENV_PYTHON) -m pip install --quiet -c constraints.txt ziglang
	$(VENV_PYTHON) fmus/cross/build_all_platforms.py --fmu-dir $(BUILD)/fmus --out $(BUILD)/fmus-all --jobs $(JOBS)

# Everything, also the C lifecycle tests and the fuzz-corpus replays that ctest runs.
build: configure
	cmake --build $(BUILD) -j $(JOBS)

# The whole-part twin, three times: UMich run 01's program engraving its wax block through every model
# (Interpolator, Workpiece, CuttingForce <-> ToolVibration, SpindlePower), compared with the recorded positions and
# spindle power after aligning the recording in time; then the process reports of the aluminium bracket and of the
# plate cut with two tools (forces, torque, power, deflection and chatter block by block, the machined surface as a
# Z-map and STL). Results in runs/<part>/.
# Builds only what it runs (`make fmus`), not the C test binaries.
MILLING_TWIN := $(abspath $(VENV))/bin/milling-twin
demo: fmus
	$(MILLING_TWIN) run scenarios/umich_part.toml --fmu-dir $(BUILD)/fmus --out runs --no-progress
	$(MILLING_TWIN) run scenarios/al_bracket.toml --fmu-dir $(BUILD)/fmus --out runs --no-progress
	$(MILLING_TWIN) run scenarios/al_plate.toml --fmu-dir $(BUILD)/fmus --out runs --no-progress

# The package (docs/packaging.md): dist/milling_twin-<version>-py3-none-<platform>.whl with every FMU
# of WHEEL_FMUS (the cross-compiled build/fmus-all/ when it holds FMUs, else build/fmus/) and the stepper library; its
# tag names the newest glibc the binaries need. setup.py copies them in; it compiles nothing.
WHEEL_FMUS ?= $(if $(wildcard $(BUILD)/fmus-all/*.fmu),$(BUILD)/fmus-all,$(BUILD)/fmus)
# WHEEL_STEPPER: the stepper library (default: WHEEL_FMUS/stepper/<arch>-linux/ from the cross-compilation, else
# build/stepper/); e.g. build/fmus-all/stepper/aarch64-linux/libmilling_stepper.so makes the aarch64 wheel,
# build/fmus-all/stepper/x86_64-windows/milling_stepper.dll the Windows one (`make wheels`: all five).
WHEEL_STEPPER ?=
wheel: fmus
	rm -rf build/python-wheel dist/milling_twin-*.whl
	MILLING_TWIN_WHEEL_FMUS=$(abspath $(WHEEL_FMUS)) \
	  MILLING_TWIN_WHEEL_STEPPER=$(if $(WHEEL_STEPPER),$(abspath $(WHEEL_STEPPER))) \
	  $(VENV_PYTHON) -m pip wheel --no-deps --quiet -w dist .
	@ls dist/milling_twin-*.whl

# One wheel per platform from the cross-compiled build/fmus-all/ (docs/packaging.md): the same FMUs, with every
# platform's binaries inside, and in each wheel its platform's stepper library: manylinux_2_17_x86_64 and _aarch64,
# win_amd64, macosx_11_0_x86_64 and _arm64.
STEPPER_LIBRARIES := x86_64-linux/libmilling_stepper.so aarch64-linux/libmilling_stepper.so \
  x86_64-windows/milling_stepper.dll x86_64-darwin/libmilling_stepper.dylib aarch64-darwin/libmilling_stepper.dylib
.PHONY: wheels
wheels: fmus-all-platforms
	rm -rf build/python-wheel dist/milling_twin-*.whl
	for library in $(STEPPER_LIBRARIES); do \
	  MILLING_TWIN_WHEEL_FMUS=$(abspath $(BUILD)/fmus-all) \
	    MILLING_TWIN_WHEEL_STEPPER=$(abspath $(BUILD)/fmus-all/stepper)/$$library \
	    $(VENV_PYTHON) -m pip wheel --no-deps --quiet -w dist . || exit 1; \
	  rm -rf build/python-wheel; \
	done
	@ls dist/milling_twin-*.whl

# The FMUs alone, for users of other FMI tools: dist/milling-twin-fmus-<version>.tar.gz (the .fmu files of
# WHEEL_FMUS, a README listing them, the licence LICENSE_FILE and the FMI headers' notice).
LICENSE_FILE ?= LICENSE
release: fmus
	$(VENV_PYTHON) -m buildtools.release --fmus $(WHEEL_FMUS) --licence $(LICENSE_FILE) --out dist

# Debian packages that some tests use, installed when missing and we are root with apt-get (CI); otherwise those
# tests are skipped with their reason. A failed install (no network, no disk) is said, and the tests that need the
# package skip:
# - clang, with its recommends (libFuzzer's runtime is one), for the short libFuzzer runs of tests/test_fuzz.py
#   (the corpus replay in ctest runs without it);
# - wine64, without recommends (~100 MB downloaded, ~700 MB installed, its prefix ~700 MB more at the first run),
#   for the Windows FMU binaries simulated under wine against the Linux ones (tests/test_cross_platform.py).
APT_INSTALL := DEBIAN_FRONTEND=noninteractive apt-get install -y -qq
test-tools:
	@need_clang=; need_wine=; \
	  command -v clang >/dev/null 2>&1 || need_clang=1; \
	  { command -v wine64 || command -v wine || ls /usr/lib/wine/wine64; } >/dev/null 2>&1 || need_wine=1; \
	  [ -z "$$need_clang$$need_wine" ] && exit 0; \
	  if [ "$$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1 || ! apt-get update -qq; then \
	    echo "not root with apt-get: clang/wine64 not installed (the tests that need them are skipped)"; exit 0; fi; \
	  [ -z "$$need_clang" ] || $(APT_INSTALL) clang >/dev/null || \
	    echo "clang not installed: the short libFuzzer run is skipped (the corpus replay still runs)"; \
	  [ -z "$$need_wine" ] || $(APT_INSTALL) --no-install-recommends wine64 >/dev/null || \
	    echo "wine64 not installed: the Windows binaries' test under wine is skipped"

test: build $(VENV)/.installed-train test-tools
	cd $(BUILD) && ctest --output-on-failure --parallel $(JOBS)
	MILLING_TWIN_FMU_DIR=$(abspath $(BUILD))/fmus $(VENV_PYTHON) -m pytest $(PYTEST_PARALLEL)
	$(MAKE) test-sanitize

# The sanitizer stage: every FMU and the stepper library built with ASan + UBSan (build-asan/, UBSan not
# recoverable), and the test suite's FMU simulations run against them with the runtimes preloaded; any report
# fails it (tests/run_sanitized.sh). Left out, and why: test_forcenet_train.py (torch: trains a network, slow
# under the preloaded ASan; its FMU-vs-torch check of the C code runs in the plain pytest run), test_fuzz.py
# (builds clang fuzzers, no FMU simulation), test_fmu_sanitizers.py (builds and preloads build-asan itself),
# test_stability.py, test_units.py and test_packaging.py (Python only: no FMU), test_wheel.py (packaging: its FMUs
# run from a fresh venv's wheel, built from the plain build), test_cross_platform.py (it compiles the FMUs' sources
# with zig, uninstrumented, and runs those binaries), test_calibrate_{fit,slot,spec,report,fmu_path,outputs}.py
# and test_documented_commands.py (it runs the docs' calibrate commands), and the tests of other files marked
# `ipopt` (a calibration among their checks: full disks, run isolation, leave one feed out): their fits
# run casadi's IPOPT, whose plugin casadi loads with RTLD_DEEPBIND, which the ASan runtime refuses outright
# (google/sanitizers#611); the FMU simulations they drive go through the same master and stepper paths as the
# scenario, master, fast-path and CLI tests that do run here.
# Four tests measure what ASan changes by design and are deselected: the RSS growth over repeated lifecycles and the
# interpolator's peak memory per line (ASan keeps freed memory in quarantine), the parser's time against program
# size (timings of an uninstrumented tool under the preloaded runtime) and fmu_loading's time against fmpy's
# (loading an instrumented library dominates both). Deselected too, as they add no instrumented code of ours (a
# quarter of the stage's time at 4cf2d97): the rebuild of every FMU from its sources/ (fmpy's CMake build, not
# instrumented, compared with the instrumented binary; in the plain run it checks the sources), the handlers'
# import and the README table's collection (Python subprocesses, no FMU), and four of the optimizer's whole-part
# loops (many runs of the same FMUs through the same master: the tiny part's, the chattering tool's with the
# simulated speed and the chatter-broken run's loops stay; the kill test is test_results.py's).
ASAN_BUILD := build-asan
SANITIZE_IGNORE := test_forcenet_train.py test_fuzz.py test_fmu_sanitizers.py test_stability.py test_units.py \
                   test_packaging.py test_calibrate_fit.py test_calibrate_slot.py test_calibrate_spec.py \
                   test_calibrate_report.py test_calibrate_fmu_path.py test_calibrate_outputs.py \
                   test_calibrate_runs.py test_calibrate_parallel.py test_documented_commands.py test_wheel.py \
                   test_cross_platform.py
SANITIZE_DESELECT := test_fmu_lifecycle.py::test_repeated_lifecycles_do_not_grow_memory \
                     test_interpolator_window.py::test_memory_grows_by_less_than_500_bytes_a_line \
                     test_interpolator_programs.py::test_parsing_is_linear_in_the_program_size \
                     test_fmu_loading.py::test_loading_is_cheaper_than_fmpys \
                     test_fmu_compliance.py::test_binary_rebuilt_from_the_fmu_sources_gives_identical_outputs \
                     test_command.py::test_every_handler_exists \
                     test_bad_input_matrix.py::test_every_row_of_the_readme_table_names_a_collected_test \
                     test_optimize_sub_blocks.py::test_a_slot_that_starts_in_air_runs_its_air_part_at_the_fastest_feed \
                     "test_optimize.py::test_a_chattering_tool_gets_the_speed_of_a_stable_pocket[zero-order]" \
                     test_optimize.py::test_a_killed_optimization_leaves_its_iterations_readable \
                     test_optimize.py::test_a_stable_speed_that_the_program_cannot_hold_keeps_s_with_a_note
test-sanitize: setup
	cmake -S . -B $(ASAN_BUILD) -DFMU_SANITIZE=ON -DPython3_EXECUTABLE=$(VENV_PYTHON) -DCMAKE_BUILD_TYPE=RelWithDebInfo
	cmake --build $(ASAN_BUILD) -j $(JOBS) --target fmu_binaries
	sh tests/run_sanitized.sh $(VENV_PYTHON) $(ASAN_BUILD) $(PYTEST_PARALLEL) -q --durations=10 -m "not ipopt" \
	  $(addprefix --ignore=tests/,$(SANITIZE_IGNORE)) $(addprefix --deselect=tests/,$(SANITIZE_DESELECT))

# libFuzzer on one fuzz target for FUZZ_TIME seconds (installs clang when missing; tests/fuzz/README.md):
# FUZZ_TARGET is gcode, forcenet or fmi_<FMU>_fmi<2|3> (`sh tests/fuzz/run_fuzz.sh list`). The committed
# corpora are replayed by ctest in every `make test`.
FUZZ_TIME ?= 600
FUZZ_TARGET ?= gcode
fuzz: build
	PYTHON=$(VENV_PYTHON) sh tests/fuzz/run_fuzz.sh $(FUZZ_TARGET) $(FUZZ_TIME)

clean:
	rm -rf $(BUILD) $(ASAN_BUILD) build-fuzz runs
