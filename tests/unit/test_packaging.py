"""Layout and packaging rules that every package relies on."""
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
