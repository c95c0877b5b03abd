# Two commands for users: `make demo` and `make test`. Both build .venv first (once).
# Needs only python3 (3.11) with venv and pip, make and a C compiler on the machine; as root it
# also installs Debian's chromium when missing (the report tests render pages in it).

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# The suite on every core (at most 4 test processes), a module's tests in one of them so that
# its fixtures are built once; each process holds a ROS domain id of its own (test/conftest.py).
# `make test PYTEST_ARGS=-n0` runs it in one process.
PYTEST_ARGS ?= -n auto --maxprocesses 4 --dist loadfile

# Keep DDS traffic on this machine (see ../shared/docs/ros2-notes.md). The tests'
# conftest sets these too, with a ROS_DOMAIN_ID of its own per test process.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export FASTDDS_BUILTIN_TRANSPORTS ?= SHM
export MPLBACKEND ?= Agg
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: demo test bench venv clean

# The package's bytecode, written once (an editable install leaves it to the first import, and
# where PYTHONDONTWRITEBYTECODE is set every process compiles every module again: 0.1 s each).
COMPILE = $(PY) -m compileall -q reducer_twin msg_adapters >/dev/null

demo: $(STAMP)
	@$(COMPILE)
	$(VENV)/bin/reducer-twin demo

test: $(STAMP)
	@$(COMPILE)
	$(PY) -m pytest $(PYTEST_ARGS)

# Benchmarks print figures; they are scripts, not timed assertions.
bench: $(STAMP)
	@set -e; for script in bench/*.py; do \
	  [ -e "$$script" ] || continue; \
	  echo "== $$script"; $(PY) "$$script"; \
	done

venv: $(STAMP)

# Reinstalled only when the dependency lists change.
$(STAMP): setup.py setup.cfg requirements-ros.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install -r requirements-ros.txt
	$(PY) -m pip install -e '.[test,fleet]'
	$(COMPILE)
	@# Debian's headless Chromium renders the reports in the tests (test/fleet/test_report.py).
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) \
	  || echo 'chromium is missing: install the Debian package chromium for the report tests'; }
	touch $@

# Removes colcon output left in the checkout; the venv stays (rm -rf .venv for that).
clean:
	rm -rf build install log reducer_twin.egg-info
