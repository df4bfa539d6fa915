# Two commands for a fresh clone: `make demo` and `make test`.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
DEMO    := demo-out
# pytest-xdist workers of the parallel test pass (the CI machine has 2 cores)
TEST_WORKERS ?= 2
# mypy's incremental cache beside the compiled CasADi functions (planner.path.nlp.compiled):
# reused by every clone on this machine when present, rebuilt when absent or stale
CACHE   ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/beamrelay

.PHONY: demo test test-system lint format report clean sysdeps

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory sysdeps
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

# open3d loads libusb-1.0 at import; the operator console's browser test drives a headless
# chromium through chromedriver. Install them with apt-get when they are missing.
sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0; \
	fi
	@if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then \
	  echo "installing chromium and chromium-driver (the console's browser test)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium chromium-driver; \
	fi

demo: $(STAMP)
	$(BIN)/python -m planner.demo $(DEMO)

test: $(STAMP)
	$(BIN)/ruff check planner schemas drivers tests examples
	$(BIN)/ruff format --check planner schemas drivers tests examples
	$(BIN)/mypy --cache-dir $(CACHE)/mypy planner schemas drivers
	$(BIN)/lint-imports --no-logo
	@echo "pytest: every test not marked serial, on $(TEST_WORKERS) workers"
	$(BIN)/pytest -m "not serial" -n $(TEST_WORKERS) --dist worksteal -raR --durations=25

# the whole simulated system, the browser, collect and the real-time probes: the tests
# marked serial, one at a time (they assert on wall-clock latencies or run the system);
# -rP: the figures the probes measured are printed for passed tests too
test-system: $(STAMP)
	@echo "pytest: the system and timing tests (marked serial), one at a time"
	$(BIN)/pytest -m serial -raRP --durations=25

lint: $(STAMP)
	$(BIN)/ruff check --fix planner schemas drivers tests examples
	$(BIN)/ruff format planner schemas drivers tests examples

report: $(STAMP)
	$(BIN)/beamrelay study all -o reports

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache .mypy_cache .ruff_cache .import_linter_cache .grimp_cache
