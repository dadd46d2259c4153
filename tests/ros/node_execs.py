"""The graph's executables as the signal and socket tests start them, and a process's sockets.

``EXECUTABLES``: every executable of the graph (issue 16) and the composed ``sim_graph``, with the
arguments that make it start and keep running alone (its parameter file from config/nodes/ when
there is one). ``executable_status(exe)`` says whether it is installed (``.venv/lib/<package>/``,
where ``ros2 run`` looks) and whether a setup.py declares it: a missing executable is a failure
only when its entry point is declared. ``sockets(pid)`` reads /proc/<pid>/net/{udp,udp6,tcp,tcp6}
for the sockets the process owns.
"""
from __future__ import annotations

import os
import pathlib
import re
import socket
import struct
from dataclasses import dataclass, field

ROOT = pathlib.Path(__file__).resolve().parents[2]
PARAMS = ROOT / "config" / "nodes"


@dataclass(frozen=True)
class Executable:
    package: str
    name: str
    params_files: tuple[str, ...] = ()  # config/nodes/<file>.yaml names (missing ones are skipped)
    ros_args: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict, hash=False, compare=False)

    @property
    def path(self) -> pathlib.Path:
        return ROOT / ".venv" / "lib" / self.package / self.name

    def argv(self, *more_ros_args: str) -> list[str]:
        args: list[str] = []
        for name in self.params_files:
            f = PARAMS / f"{name}.yaml"
            if f.is_file():
                args += ["--params-file", str(f)]
        args += list(self.ros_args) + list(more_ros_args)
        return [str(self.path)] + (["--ros-args", *args] if args else [])

    def __str__(self) -> str:
        return f"{self.package}/{self.name}"


EXECUTABLES = (
    Executable("sim_bridge", "sim_bridge", ("sim_bridge",)),
    Executable("controller_node", "controller", ("controller",)),
    Executable("planner_node", "guide_path", ("guide_path",)),
    Executable("planner_node", "contact_search", ("contact_search",)),
    Executable("planner_node", "primitive_adaptation", ("primitive_adaptation",)),
    Executable("climb_coordinator", "climb_coordinator", ("climb_coordinator",)),
    Executable("climb_coordinator", "recorder", ("recorder",)),
    Executable("climb_coordinator", "sim_graph", ("sim_bridge", "controller")),
)


def declared_entry_points(package: str) -> set[str]:
    """console_scripts names declared in src/<package>/setup.py."""
    setup = ROOT / "src" / package / "setup.py"
    if not setup.is_file():
        return set()
    text = setup.read_text()
    match = re.search(r"console_scripts[\"']\s*:\s*\[(.*?)\]", text, re.S)
    if not match:
        return set()
    return set(re.findall(r"[\"']\s*([A-Za-z0-9_]+)\s*=", match.group(1)))


def executable_status(exe: Executable) -> str:
    """'installed', 'missing' (declared in setup.py but not installed: a failure) or 'undeclared'."""
    if exe.path.is_file() and os.access(exe.path, os.X_OK):
        return "installed"
    return "missing" if exe.name in declared_entry_points(exe.package) else "undeclared"


# ------------------------------------------------------------------------------------ sockets
@dataclass(frozen=True)
class Socket:
    table: str  # udp | udp6 | tcp | tcp6
    local: str  # ip
    port: int
    remote: str

    def __str__(self) -> str:
        return f"{self.table} {self.local}:{self.port} -> {self.remote}"


def _inodes(pid: int) -> set[str]:
    out = set()
    fd_dir = f"/proc/{pid}/fd"
    for fd in os.listdir(fd_dir):
        try:
            link = os.readlink(os.path.join(fd_dir, fd))
        except OSError:  # closed meanwhile
            continue
        if link.startswith("socket:["):
            out.add(link[len("socket:["):-1])
    return out


def _ip(hexaddr: str, v6: bool) -> tuple[str, int]:
    ip, port = hexaddr.split(":")
    if v6:
        raw = bytes.fromhex(ip)
        raw = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
        return socket.inet_ntop(socket.AF_INET6, raw), int(port, 16)
    return socket.inet_ntoa(struct.pack("<I", int(ip, 16))), int(port, 16)


def sockets(pid: int) -> list[Socket]:
    """Every UDP / TCP (v4 and v6) socket owned by process ``pid`` (Linux /proc)."""
    owned = _inodes(pid)
    rows = []
    for table in ("udp", "udp6", "tcp", "tcp6"):
        try:
            lines = pathlib.Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]
        except FileNotFoundError:
            continue
        for line in lines:
            cols = line.split()
            if len(cols) > 9 and cols[9] in owned:
                local, port = _ip(cols[1], table.endswith("6"))
                remote, rport = _ip(cols[2], table.endswith("6"))
                rows.append(Socket(table, local, port, f"{remote}:{rport}"))
    return rows


def is_loopback(sock: Socket) -> bool:
    import ipaddress

    return ipaddress.ip_address(sock.local).is_loopback
