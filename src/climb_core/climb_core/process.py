"""Child processes that do not outlive the process that started them (Linux)."""
from __future__ import annotations

import ctypes
import os
import signal

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(sig: int = signal.SIGKILL) -> None:
    """In a child (a ``preexec_fn`` or a pool initializer): the kernel sends it ``sig`` when its
    parent dies, whatever killed the parent (SIGKILL included); a child whose parent died before
    this call exits at once. Elsewhere than Linux (no ``prctl``) only the second part applies."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, sig, 0, 0, 0)
    except OSError:
        pass
    if os.getppid() == 1:  # reparented to init: the parent is gone already
        os._exit(1)
