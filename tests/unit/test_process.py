"""climb_core.process.die_with_parent: a child that called it dies with its parent, even when the
parent is killed with SIGKILL (nothing of the parent runs to stop it)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

# the parent: starts a child that calls die_with_parent() and sleeps, prints the child's pid, waits
PARENT = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c",
    "from climb_core.process import die_with_parent; die_with_parent(); import time; time.sleep(60)"])
print(child.pid, flush=True)
time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (not reaped yet by init) counts as dead
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split(")")[-1].split()[0] != "Z"


def test_a_child_dies_with_its_killed_parent():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        time.sleep(1.0)  # the child has imported climb_core and called prctl
        assert _alive(child)
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        deadline = time.monotonic() + 10.0
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(child), "the child outlived its SIGKILLed parent"
    finally:
        parent.kill()
        try:
            os.kill(child, signal.SIGKILL)
        except (ProcessLookupError, UnboundLocalError):
            pass
