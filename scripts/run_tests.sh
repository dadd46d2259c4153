#!/usr/bin/env bash
# `make test`: the library and simulator tests (tests/unit, tests/sim: CPU-bound, no wall-time
# bounds) on two pytest-xdist workers, one per core, the executed climbs first (marker heavy,
# tests/conftest.py) so that both cores share them; then the ROS tests (tests/ros: their own node processes, lock-step pairs and
# wall-time bounds need the whole machine) in one process. Extra arguments go to both pytest runs.
# --maxschedchunk 2: xdist's load scheduler hands each worker a first chunk of a quarter of its
# share (~98 tests), so that the first worker got all five executed climbs in a row and the
# other idled (measured: unit + sim 727 s, one worker ran 4 tests and the other 688); in chunks of
# two, the climbs are dealt two and two and the light tests fill the gaps.
# Exit code: non-zero when either part failed (both parts always run).
set -u
cd "$(dirname "$0")/.."
PY=.venv/bin/python
t0=$(date +%s)
# one BLAS / OpenMP thread per worker: two workers already use both cores
OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \
  "$PY" -m pytest -q -n 2 --dist load --maxschedchunk 2 --durations=15 tests/unit tests/sim "$@"
lib=$?
t1=$(date +%s)
"$PY" -m pytest -q --durations=15 tests/ros "$@"
ros=$?
t2=$(date +%s)
echo "make test: tests/unit + tests/sim exit $lib in $((t1 - t0)) s (2 workers); tests/ros exit $ros in $((t2 - t1)) s; total $((t2 - t0)) s"
[ "$lib" -eq 0 ] && [ "$ros" -eq 0 ]
