# Two public commands: `make demo` and `make test`. Both set the project up first if needed.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
# The loopback profile applied as is (every socket on 127.0.0.1, measured: docs/interfaces.md)
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= SYSTEM_DEFAULT
export FASTRTPS_DEFAULT_PROFILES_FILE ?= $(CURDIR)/config/fastdds_localhost.xml
export ROS_DOMAIN_ID ?= 42
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp

.PHONY: setup test test-fast demo bench clean

setup:
	@bash scripts/setup_env.sh

# The whole suite in one process: measured, running the ROS tests beside the CPU-bound
# in-process climbs (pytest-xdist -n 2) took longer (31 min) and broke their wall-time bounds.
test: setup
	$(PY) -m pytest -q --durations=25 tests

test-fast: setup
	$(PY) -m pytest -q tests/unit

demo: setup
	$(PY) scripts/demo.py

bench: setup
	$(PY) scripts/bench_core.py

clean:
	rm -rf build ros_ws/build ros_ws/install ros_ws/log out
