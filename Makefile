# One-command entry points (see README.md):
#   make all    set everything up, then run `snakemake --cores 2 all` on the default config
#   make test   set everything up, then lint (ruff, snakefmt, snakemake --lint) and run the whole test suite
#               in two pytest workers (TEST_WORKERS=1 for one)
#   make test-fast  set everything up, then run the tests that need neither the published data nor
#               Snakemake jobs (pytest -m "not slow"; the slow ones carry @pytest.mark.slow, tests/conftest.py checks it)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
CORES  ?= 2
# pytest workers of `make test` (pytest-xdist, one test module per worker at a time)
TEST_WORKERS ?= 2

.PHONY: all test test-fast check format install system-deps bench report clean

all: install
	$(BIN)/snakemake --cores $(CORES) all

test: install check
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-fast: install
	$(BIN)/python -m pytest -q -m "not slow" -n $(TEST_WORKERS) --dist loadfile

# Formatting and lint: ruff for Python, snakefmt for the rule files, Snakemake's own lint.
check: install
	$(BIN)/ruff check workflow tests benchmarks
	$(BIN)/ruff format --check workflow tests benchmarks
	$(BIN)/snakefmt --check Snakefile workflow/Snakefile workflow/rules
	$(BIN)/snakemake --lint

format: install
	$(BIN)/ruff check --fix workflow tests benchmarks
	$(BIN)/ruff format workflow tests benchmarks
	$(BIN)/snakefmt Snakefile workflow/Snakefile workflow/rules

install: system-deps $(STAMP)

# open3d needs libusb-1.0 from Debian, the map viewer's browser test Debian's Chromium and its
# driver; install them when missing (as root), else say how (without Chromium that test skips).
system-deps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing libusb-1.0-0 (needed by open3d)"; \
	    (apt-get install -y -q libusb-1.0-0 || (apt-get update -q && apt-get install -y -q libusb-1.0-0)) >/dev/null; \
	  else \
	    echo "open3d needs libusb-1.0: run 'sudo apt-get install libusb-1.0-0'" >&2; exit 1; \
	  fi; \
	fi
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing chromium and chromium-driver (the map viewer's browser test)"; \
	    export DEBIAN_FRONTEND=noninteractive; \
	    (apt-get install -y -q chromium chromium-driver || (apt-get update -q && apt-get install -y -q chromium chromium-driver)) >/dev/null; \
	  else \
	    echo "the map viewer's browser test needs Chromium: run 'sudo apt-get install chromium chromium-driver'" >&2; \
	  fi; \
	fi

# the workflow's pins and the development tools, then this clone's package, editable (the workflow
# needs no install from a clone: it puts its own folder on the rules' path; the install gives the
# `flatlandia` command and `import flatlandia` outside the workflow)
$(STAMP): envs/requirements.txt envs/requirements-dev.txt envs/constraints.txt pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -r envs/requirements.txt -r envs/requirements-dev.txt -c envs/constraints.txt
	$(BIN)/python -m pip install -q --no-deps -e .
	touch $(STAMP)

bench: install
	$(BIN)/python benchmarks/bench_recover.py

report: install
	$(BIN)/snakemake --cores $(CORES) all
	$(BIN)/snakemake --report results/report.html

clean:
	rm -rf results logs .snakemake
