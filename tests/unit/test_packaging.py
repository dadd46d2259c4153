"""Layout and packaging rules that every package relies on."""
import ast
import pathlib
import subprocess
import sys
import xml.etree.ElementTree as ET

ROOT = pathlib.Path(__file__).resolve().parents[2]
PYTHON_PACKAGES = ["climb_core", "msgs_py", "sim_bridge", "controller_node", "planner_node", "climb_coordinator"]


def test_every_package_is_an_ament_package():
    for name in PYTHON_PACKAGES + ["climb_msgs"]:
        pkg = ROOT / "src" / name / "package.xml"
        root = ET.parse(pkg).getroot()
        assert root.findtext("name") == name
        build_type = root.find("export/build_type").text
        assert build_type == ("ament_cmake" if name == "climb_msgs" else "ament_python")
        assert (ROOT / "ros_ws" / "src" / name).resolve() == (ROOT / "src" / name).resolve()


def test_libraries_do_not_import_rclpy():
    """The ROS-free libraries must import without pulling rclpy in (nodes are thin)."""
    code = (
        "import sys, importlib\n"
        "for m in ['climb_core', 'climb_core.robot', 'climb_core.ladder', 'climb_core.environment',"
        " 'climb_core.contact', 'climb_core.feasibility', 'climb_core.params',"
        " 'msgs_py', 'sim_bridge.backend', 'controller_node.qp', 'planner_node.msp']:\n"
        "    importlib.import_module(m)\n"
        "bad = [m for m in sys.modules if m == 'rclpy' or m.startswith('rclpy.')]\n"
        "assert not bad, bad\n"
        "print('clean')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "clean" in out.stdout


def test_generated_interfaces_import():
    from climb_msgs.msg import Hold, JointCommand, WholeBodyPlan  # noqa: F401
    from climb_msgs.srv import Cancel, Climb, SimPerturb, SimReset  # noqa: F401

    assert JointCommand.TORQUE == 0 and JointCommand.PWM == 1 and JointCommand.POSITION == 2


#: The ROS shells: executables' node modules and the ROS boundary helpers. Everything else in the
#: Python packages is library code that tests and benchmarks call without ROS.
ROS_SHELLS = {"node.py", "node_kit.py", "topics.py", "sim_graph.py", "env_probe.py"}
LIBRARY_PACKAGES = ["climb_core", "sim_bridge", "controller_node", "planner_node", "climb_coordinator"]


def _is_shell(path: pathlib.Path) -> bool:
    return path.name in ROS_SHELLS or path.name.endswith("_node.py")


def _rclpy_imports(path: pathlib.Path) -> list[int]:
    """Line numbers of every `import rclpy...` / `from rclpy... import` in the file, at any depth
    (a lazy import inside a function still makes the library depend on ROS)."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import) and any(a.name == "rclpy" or a.name.startswith("rclpy.") for a in node.names):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.module and (node.module == "rclpy"
                                                                   or node.module.startswith("rclpy.")):
            lines.append(node.lineno)
    return lines


def test_every_library_module_is_free_of_rclpy():
    """Walk every module of the library packages: only the node shells may import rclpy."""
    offenders = []
    for pkg in LIBRARY_PACKAGES:
        for path in sorted((ROOT / "src" / pkg / pkg).rglob("*.py")):
            if _is_shell(path):
                continue
            offenders += [f"{path.relative_to(ROOT)}:{line}" for line in _rclpy_imports(path)]
    assert not offenders, f"library modules importing rclpy: {offenders}"


def test_every_library_module_imports_without_rclpy():
    """Import every library module (and msgs_py's conversions) in one fresh interpreter: none may
    pull rclpy in as a side effect (through another module)."""
    modules = []
    for pkg in LIBRARY_PACKAGES + ["msgs_py"]:
        for path in sorted((ROOT / "src" / pkg / pkg).rglob("*.py")):
            if _is_shell(path) or path.name == "__main__.py":
                continue
            rel = path.relative_to(ROOT / "src" / pkg).with_suffix("")
            name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
            modules.append(name)
    code = (
        "import sys, importlib, json\n"
        f"mods = {modules!r}\n"
        "bad = []\n"
        "for m in mods:\n"
        "    importlib.import_module(m)\n"
        "    if any(k == 'rclpy' or k.startswith('rclpy.') for k in sys.modules):\n"
        "        bad.append(m); break\n"
        "print(json.dumps(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]", f"rclpy pulled in by: {out.stdout}"


def _imports_of(path: pathlib.Path, module: str) -> list[int]:
    """Line numbers of every import of ``module`` (or a submodule) in the file, at any depth."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import) and any(a.name == module or a.name.startswith(module + ".")
                                                for a in node.names):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.module and (node.module == module
                                                                   or node.module.startswith(module + ".")):
            lines.append(node.lineno)
    return lines


def test_the_core_is_simulator_free():
    """climb_core is shared by planner, controller and bridge: no module of it imports PyBullet
    (the simulator's bodies and URDF are the bridge's: sim_bridge.world_bodies, sim_bridge.sim_urdf)."""
    offenders = [f"{path.relative_to(ROOT)}:{line}"
                 for path in sorted((ROOT / "src" / "climb_core" / "climb_core").rglob("*.py"))
                 for line in _imports_of(path, "pybullet")]
    assert not offenders, f"climb_core modules importing pybullet: {offenders}"
    # nor does it carry the simulator's rules (PyBullet's friction combination, its body poses)
    import ast

    rules = [f"{path.relative_to(ROOT)}:{node.lineno} {node.name}"
             for path in sorted((ROOT / "src" / "climb_core" / "climb_core").rglob("*.py"))
             for node in ast.walk(ast.parse(path.read_text()))
             if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and "pybullet" in node.name.lower()]
    assert not rules, f"PyBullet code in climb_core (sim_bridge.world_bodies owns it): {rules}"
