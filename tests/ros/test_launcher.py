"""The launcher: one node list (config/graph.yaml) behind scripts/climb.py and the launch file, and
a graph that never outlives its launcher.

The `launch` / `launch_ros` wheels do not exist here: generate_launch_description() runs against
minimal stand-in modules that record the declared nodes, which are compared with the processes
climb_coordinator.graph starts for the same layout."""
from __future__ import annotations

import importlib.util
import os
import pathlib
import signal
import subprocess
import sys
import textwrap
import time
import types

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
LAUNCH_FILE = ROOT / "src" / "climb_coordinator" / "launch" / "climb.launch.py"
GRAPH_NODES = {"sim_bridge", "controller", "guide_path", "contact_search", "primitive_adaptation",
               "climb_coordinator", "recorder"}


@pytest.fixture
def stand_in_launch(monkeypatch):
    """Minimal `launch` and `launch_ros.actions` modules: Node records its keyword arguments."""
    launch = types.ModuleType("launch")
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")

    class LaunchDescription:
        def __init__(self, entities=()):
            self.entities = list(entities)

    class Node:
        def __init__(self, **kwargs):
            self.kwargs = kwargs

    launch.LaunchDescription = LaunchDescription
    actions.Node = Node
    launch_ros.actions = actions
    for name, module in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("climb_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _launched(module, layout: str) -> dict[str, dict]:
    out = {}
    for node in module.generate_launch_description(layout).entities:
        kw = node.kwargs
        files = [p for p in kw["parameters"] if isinstance(p, str)]
        params = {}
        for p in kw["parameters"]:
            if isinstance(p, dict):
                params.update(p)
        prefix = kw.get("prefix", "")
        out[kw["name"]] = {"package": kw["package"], "executable": kw["executable"], "files": files,
                           "params": params, "nice": int(prefix.split()[-1]) if prefix else 0}
    return out


def _started(layout: str) -> dict[str, dict]:
    """What climb_coordinator.graph starts (scripts/climb.py's launcher) for the layout, parsed
    back from the command lines."""
    from climb_coordinator.graph import _param_text, command, load_graph

    out = {}
    for spec in load_graph().layout(layout):
        argv = command(spec, prefix=sys.prefix)  # what GraphProcesses.start() runs
        assert argv[1] == "--ros-args"
        exe = pathlib.Path(argv[0])
        files = [argv[i + 1] for i, a in enumerate(argv) if a == "--params-file"]
        params = dict(argv[i + 1].split(":=", 1) for i, a in enumerate(argv) if a == "-p")
        out[spec.name] = {"package": exe.parent.name, "executable": exe.name, "files": files, "params": params,
                          "to_text": _param_text, "nice": spec.nice}
    return out


@pytest.mark.parametrize("layout", ["processes", "composed"])
def test_launch_file_declares_what_the_launcher_starts(stand_in_launch, layout):
    launched = _launched(stand_in_launch, layout)
    started = _started(layout)
    assert set(launched) == set(started)
    if layout == "processes":
        assert set(launched) == GRAPH_NODES
    else:
        assert "sim_graph" in launched and not {"sim_bridge", "controller"} & set(launched)
        assert {"sim_graph", "guide_path", "climb_coordinator"} <= set(launched)
    for name, s in started.items():
        la = launched[name]
        assert (la["package"], la["executable"]) == (s["package"], s["executable"]), name
        assert la["files"] == s["files"], name
        assert la["nice"] == s["nice"], name
        assert {k: s["to_text"](v) for k, v in la["params"].items()} == s["params"], name
    # the controller waits for the coordinator, the bridge for the controller
    ctl = launched["controller" if layout == "processes" else "sim_graph"]["params"]
    assert ctl["autostart"] is False
    if layout == "processes":
        assert "config/nodes/controller.yaml" in launched["controller"]["files"][0].replace(os.sep, "/")


def test_every_graph_executable_is_installed():
    from climb_coordinator.graph import load_graph

    cfg = load_graph()
    for spec in list(cfg.nodes) + [cfg.composed]:
        assert spec.executable_path().is_file(), f"{spec.executable_path()} (run make setup)"


def test_graph_config_errors_name_the_field(tmp_path):
    from climb_core.errors import SpecError
    from climb_coordinator.graph import load_graph

    bad = tmp_path / "graph.yaml"
    bad.write_text("graph:\n  nodes:\n    - {name: a, package: p}\n  composed: {name: c, package: p, executable: e}\n")
    with pytest.raises(SpecError) as err:
        load_graph(bad)
    assert err.value.field == "graph.nodes[0].executable"
    with pytest.raises(SpecError):
        load_graph().layout("threads")


def test_children_die_with_a_sigkilled_launcher(tmp_path):
    """PR_SET_PDEATHSIG: a launcher killed with SIGKILL takes its whole graph with it."""
    prefix = tmp_path / "prefix"
    for pkg, exe in (("pkg_a", "sleeper_a"), ("pkg_b", "sleeper_b")):
        path = prefix / "lib" / pkg / exe
        path.parent.mkdir(parents=True)
        path.write_text(f"#!{sys.executable}\nimport time\nwhile True:\n    time.sleep(1)\n")
        path.chmod(0o755)
    launcher = tmp_path / "launcher.py"
    launcher.write_text(textwrap.dedent(f"""
        import sys, time
        from climb_coordinator.graph import GraphProcesses, NodeSpec
        g = GraphProcesses([NodeSpec("a", "pkg_a", "sleeper_a"), NodeSpec("b", "pkg_b", "sleeper_b")],
                           prefix={str(prefix)!r})
        g.start()
        print(" ".join(str(p) for p in g.pids().values()), flush=True)
        time.sleep(600)
    """))
    proc = subprocess.Popen([sys.executable, str(launcher)], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert len(pids) == 2
        for pid in pids:
            os.kill(pid, 0)  # alive
            assert os.getpgid(pid) == pid  # each child leads its own process group
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        deadline = time.monotonic() + 10
        alive = pids
        while alive and time.monotonic() < deadline:
            alive = [p for p in pids if _alive(p)]
            time.sleep(0.05)
        assert not alive, f"children {alive} outlived their SIGKILLed launcher"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead (its parent, init, reaps it)
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1].split()[0] != "Z"
    except OSError:
        return False
