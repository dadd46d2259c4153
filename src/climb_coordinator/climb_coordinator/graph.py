"""The climb graph's node list (config/graph.yaml) and a launcher of its processes (no rclpy).

    cfg = load_graph()
    nodes = cfg.layout("processes")                  # or "composed" (bridge + controller in sim_graph)
    graph = GraphProcesses(nodes, extra_params={"recorder": {"bag_path": "out/x/bag"}}, log_dir="out/x/logs")
    graph.start()
    ...
    dead = graph.crashed()                           # [(name, returncode)] of nodes that ended
    graph.stop()                                     # SIGINT, then SIGTERM, then SIGKILL; every child reaped

Each child runs in its own process group and gets PR_SET_PDEATHSIG (SIGKILL) before its exec, so
that the whole graph dies with the launcher even when the launcher is killed with SIGKILL.
Children inherit the loopback DDS environment (climb_core.ros_env.local_dds_env).
"""
from __future__ import annotations

import functools
import os
import pathlib
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field, replace
from typing import Any

import yaml

from climb_core.errors import SpecError
from climb_core.process import die_with_parent
from climb_core.ros_env import local_dds_env, project_root

LAYOUTS = ("processes", "composed")


@dataclass(frozen=True)
class NodeSpec:
    name: str
    package: str
    executable: str
    params_files: tuple[str, ...] = ()  # relative to the project root (or absolute)
    params: dict = field(default_factory=dict)  # dotted name -> value
    optional: bool = False  # started only when its executable exists
    planner: bool = False  # gets config/climb.yaml's planner_overrides
    replaces: tuple[str, ...] = ()  # a composed process: the nodes it runs
    nice: int = 0  # process niceness (negative: the lock-step pair keeps its pace on a loaded machine)

    def executable_path(self, prefix: str | os.PathLike | None = None) -> pathlib.Path:
        """Where `ros2 run <package> <executable>` finds it: <prefix>/lib/<package>/<executable>."""
        return pathlib.Path(prefix or sys.prefix) / "lib" / self.package / self.executable

    def params_paths(self, root: pathlib.Path | None = None) -> list[pathlib.Path]:
        root = root or project_root()
        return [pathlib.Path(f) if pathlib.Path(f).is_absolute() else root / f for f in self.params_files]


@dataclass(frozen=True)
class GraphConfig:
    nodes: tuple[NodeSpec, ...]
    composed: NodeSpec

    def layout(self, name: str = "processes", with_optional: bool = True) -> list[NodeSpec]:
        """The processes of a layout: ``processes`` (one per node) or ``composed`` (the composed
        process replaces its nodes, at the place of the first one)."""
        if name not in LAYOUTS:
            raise SpecError("graph", f"must be one of {', '.join(LAYOUTS)} (or inprocess for scripts/climb.py), "
                                     f"got {name!r}")
        out: list[NodeSpec] = []
        for n in self.nodes:
            if n.optional and not with_optional:
                continue
            if name == "composed" and n.name in self.composed.replaces:
                if self.composed not in out:
                    files = tuple(f for r in self.composed.replaces for f in self.node(r).params_files)
                    params: dict = {}
                    for r in self.composed.replaces:
                        params.update(self.node(r).params)
                    out.append(replace(self.composed, params_files=files, params=params))
                continue
            out.append(n)
        return out

    def node(self, name: str) -> NodeSpec:
        for n in self.nodes:
            if n.name == name:
                return n
        raise KeyError(name)


def _spec(d: Any, where: str) -> NodeSpec:
    if not isinstance(d, dict):
        raise SpecError(where, "must be a mapping")
    for key in ("name", "package", "executable"):
        if not isinstance(d.get(key), str) or not d[key]:
            raise SpecError(f"{where}.{key}", "is required (a non-empty string)")
    unknown = set(d) - {"name", "package", "executable", "params_files", "params", "optional", "planner", "replaces",
                        "nice"}
    if unknown:
        raise SpecError(f"{where}.{sorted(unknown)[0]}", "unknown key")
    files = d.get("params_files") or []
    params = d.get("params") or {}
    if not isinstance(files, list) or not isinstance(params, dict):
        raise SpecError(where, "params_files must be a list, params a mapping")
    nice = d.get("nice", 0)
    if isinstance(nice, bool) or not isinstance(nice, int) or not -20 <= nice <= 19:
        raise SpecError(f"{where}.nice", f"must be an integer in [-20, 19], got {nice!r}")
    return NodeSpec(d["name"], d["package"], d["executable"], tuple(str(f) for f in files), dict(params),
                    bool(d.get("optional", False)), bool(d.get("planner", False)),
                    tuple(d.get("replaces") or ()), nice)


def load_graph(path: str | os.PathLike | None = None) -> GraphConfig:
    """config/graph.yaml (SpecError naming the field when malformed)."""
    path = pathlib.Path(path) if path is not None else project_root() / "config" / "graph.yaml"
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise SpecError("graph", f"cannot read {path}: {exc}") from None
    g = doc.get("graph") if isinstance(doc, dict) else None
    if not isinstance(g, dict) or not isinstance(g.get("nodes"), list):
        raise SpecError("graph.nodes", "must be a list of nodes")
    nodes = tuple(_spec(d, f"graph.nodes[{i}]") for i, d in enumerate(g["nodes"]))
    names = [n.name for n in nodes]
    if len(set(names)) != len(names):
        raise SpecError("graph.nodes", "node names must be unique")
    composed = _spec(g.get("composed"), "graph.composed")
    for r in composed.replaces:
        if r not in names:
            raise SpecError("graph.composed.replaces", f"unknown node {r!r}")
    return GraphConfig(nodes, composed)


def planner_overrides() -> dict:
    """config/climb.yaml's planner_overrides (what the in-process climb applies to the planner)."""
    from .settings import load_climb_settings

    return dict(load_climb_settings().planner_overrides)


def _param_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_param_text(v) for v in value) + "]"
    if isinstance(value, str):
        return value
    return repr(value)


def node_params(spec: NodeSpec, extra: dict | None = None) -> dict:
    """The ``-p`` parameters of a node: graph.yaml's, the planner overrides of a planning node,
    then ``extra`` (the launcher's per-run values)."""
    params = dict(spec.params)
    if spec.planner:
        params.update(planner_overrides())
    params.update(extra or {})
    return params


def command(spec: NodeSpec, extra_params: dict | None = None, prefix: str | None = None,
            root: pathlib.Path | None = None) -> list[str]:
    """argv of one node: its executable, ``--ros-args``, its parameter files (existing ones) and
    ``-p name:=value`` per parameter."""
    argv = [str(spec.executable_path(prefix)), "--ros-args"]
    for path in spec.params_paths(root):
        if path.is_file():
            argv += ["--params-file", str(path)]
    for k, v in node_params(spec, extra_params).items():
        argv += ["-p", f"{k}:={_param_text(v)}"]
    return argv


# ------------------------------------------------------------------------------ processes

def _child_setup(nice: int = 0) -> None:
    """In the child, before exec: its own process group, its niceness (ignored when not
    permitted), and SIGKILL when the launcher dies."""
    os.setpgid(0, 0)
    if nice:
        try:
            os.nice(nice)
        except OSError:
            pass
    die_with_parent(signal.SIGKILL)


class GraphProcesses:
    """The processes of a layout, started, watched and stopped together."""

    def __init__(self, nodes: list[NodeSpec], extra_params: dict[str, dict] | None = None,
                 log_dir: str | os.PathLike | None = None, env: dict | None = None, prefix: str | None = None,
                 domain_id: int | None = None):
        self.specs = [n for n in nodes if not n.optional or n.executable_path(prefix).exists()]
        self.skipped = [n.name for n in nodes if n not in self.specs]
        self.extra = extra_params or {}
        self.log_dir = pathlib.Path(log_dir) if log_dir is not None else None
        self.env = local_dds_env(env, domain_id)
        self.prefix = prefix
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: list = []
        self.expected_exit: set[str] = set()

    def commands(self) -> dict[str, list[str]]:
        return {n.name: command(n, self.extra.get(n.name), self.prefix) for n in self.specs}

    def start(self) -> None:
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
        specs = {n.name: n for n in self.specs}
        for name, argv in self.commands().items():
            if not pathlib.Path(argv[0]).exists():
                self.stop()
                raise SpecError(f"graph.{name}", f"executable {argv[0]} not found (run `make setup`)")
            out = subprocess.DEVNULL
            if self.log_dir is not None:
                out = open(self.log_dir / f"{name}.log", "wb")
                self._logs.append(out)
            self.procs[name] = subprocess.Popen(argv, env=self.env, cwd=str(project_root()), stdout=out,
                                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                                preexec_fn=functools.partial(_child_setup, specs[name].nice))

    def pids(self) -> dict[str, int]:
        return {name: p.pid for name, p in self.procs.items()}

    def crashed(self) -> list[tuple[str, int]]:
        """Nodes that ended on their own (name, return code)."""
        return [(name, p.returncode) for name, p in self.procs.items()
                if name not in self.expected_exit and p.poll() is not None]

    def stop_node(self, name: str, timeout: float = 10.0) -> int | None:
        """SIGINT one node and wait for it (then SIGTERM, SIGKILL)."""
        p = self.procs.get(name)
        if p is None:
            return None
        self.expected_exit.add(name)
        _stop([p], timeout)
        return p.returncode

    def stop(self, timeout: float = 10.0) -> dict[str, int | None]:
        """Every child: SIGINT (the nodes exit cleanly), SIGTERM after ``timeout``, SIGKILL after
        2 s more; returns the exit codes."""
        self.expected_exit.update(self.procs)
        _stop(list(self.procs.values()), timeout)
        for f in self._logs:
            try:
                f.close()
            except OSError:
                pass
        self._logs = []
        return {name: p.returncode for name, p in self.procs.items()}

    def log_tail(self, name: str, chars: int = 2000) -> str:
        if self.log_dir is None:
            return ""
        try:
            return (self.log_dir / f"{name}.log").read_text(errors="replace")[-chars:]
        except OSError:
            return ""


def _signal(p: subprocess.Popen, sig: int) -> None:
    if p.poll() is not None:
        return
    try:
        os.killpg(p.pid, sig)  # the child's own group (it made it before its exec)
    except (ProcessLookupError, PermissionError):
        try:
            p.send_signal(sig)
        except ProcessLookupError:
            pass


def _stop(procs: list[subprocess.Popen], timeout: float) -> None:
    for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 3.0), (signal.SIGKILL, 5.0)):
        alive = [p for p in procs if p.poll() is None]
        if not alive:
            break
        for p in alive:
            _signal(p, sig)
        deadline = time.monotonic() + wait
        for p in alive:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
    for p in procs:  # reap
        if p.poll() is None:
            try:
                p.wait(1.0)
            except subprocess.TimeoutExpired:
                pass


def launch_entries(layout: str = "processes", extra_params: dict[str, dict] | None = None,
                   root: pathlib.Path | None = None) -> list[dict]:
    """What a launch file declares for a layout: per node ``package``, ``executable``, ``name``,
    ``params_files`` (absolute paths of the existing files) and ``params`` (the ``-p`` values).
    The optional nodes are included (a full install has them)."""
    root = root or project_root()
    out = []
    for n in load_graph(root / "config" / "graph.yaml").layout(layout):
        out.append({"package": n.package, "executable": n.executable, "name": n.name, "nice": n.nice,
                    "params_files": [str(p) for p in n.params_paths(root) if p.is_file()],
                    "params": node_params(n, (extra_params or {}).get(n.name))})
    return out
