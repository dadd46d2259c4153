#!/usr/bin/env bash
# `make test`: the library and simulator tests (tests/unit, tests/sim: CPU-bound, no wall-time
# bounds), then the ROS tests (tests/ros: node processes), each part on two pytest-xdist workers,
# one per core.
# Part 1, --dist load --maxschedchunk 2: the executed climbs (marker heavy, tests/conftest.py) come
#   first and are dealt two at a time, so that both cores share them and the light tests fill the
#   gaps (with xdist's default first chunk, a quarter of a worker's share, one worker got all the
#   climbs in a row and the other idled: measured, docs/benchmarks.md).
# Part 2, --dist loadscope --no-loadscope-reorder: a module's tests (a class's, for test classes)
#   run on one worker, so that a class- or module-scoped fixture (a graph of node processes, a
#   bridge) starts once, and the units go out in collection order: the graph climbs (heavy) first.
#   Each worker has its own ROS domain (tests/conftest.py), so two graphs never see each other.
#   The ROS tests do not run beside the simulator tests: measured, with an in-process climb on the
#   other core a node's SIGINT exit and a recorder's first messages missed their bounds.
# One BLAS / OpenMP thread per process: two workers already use both cores.
# The tests marked long (minutes-long executions past this budget) are make test-long's, not run here.
# Extra arguments go to both pytest runs. Exit code: non-zero when either part failed (both run).
set -u
cd "$(dirname "$0")/.."
PY=.venv/bin/python
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
t0=$(date +%s)
"$PY" -m pytest -q -n 2 --dist load --maxschedchunk 2 --durations=15 -m "not long" tests/unit tests/sim "$@"
lib=$?
t1=$(date +%s)
"$PY" -m pytest -q -n 2 --dist loadscope --no-loadscope-reorder --durations=15 tests/ros "$@"
ros=$?
t2=$(date +%s)
echo "make test: tests/unit + tests/sim exit $lib in $((t1 - t0)) s; tests/ros exit $ros in $((t2 - t1)) s; total $((t2 - t0)) s (2 workers each)"
[ "$lib" -eq 0 ] && [ "$ros" -eq 0 ]
