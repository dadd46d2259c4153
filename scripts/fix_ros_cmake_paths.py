"""Point the ROS wheels' exported CMake files at this interpreter's include dirs.

The ros-jazzy-* wheels are built on manylinux, so their CMake config files name the build
machine's Python (/opt/python/cp311-cp311/...) and its numpy. Building an interface package
against them fails until those paths name the venv's interpreter. Usage: fix_ros_cmake_paths.py VENV
"""
import pathlib
import re
import sys
import sysconfig

import numpy


def main(venv: str) -> int:
    include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    # numpy include dirs first (they are longer and contain the interpreter prefix).
    patterns = [
        (re.compile(r"/opt/python/cp311-cp311/lib/python3\.11/site-packages/numpy/(_core|core)/include"), numpy_include),
        (re.compile(r"/opt/_internal/cpython-3\.11[^/;\"]*/lib/python3\.11/site-packages/numpy/(_core|core)/include"), numpy_include),
        (re.compile(r"/opt/python/cp311-cp311/include/python3\.11"), include),
        (re.compile(r"/opt/_internal/cpython-3\.11[^/;\"]*/include/python3\.11"), include),
    ]
    changed = 0
    for path in pathlib.Path(venv, "share").rglob("*.cmake"):
        text = path.read_text(errors="surrogateescape")
        new = text
        for pattern, repl in patterns:
            new = pattern.sub(repl, new)
        if new != text:
            path.write_text(new, errors="surrogateescape")
            changed += 1
    print(f"[setup] rewrote Python paths in {changed} CMake files")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
