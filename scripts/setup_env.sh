#!/usr/bin/env bash
# Creates .venv from nothing and builds the project into it. Idempotent: each step leaves a
# stamp keyed on the hash of its inputs, so a second run takes seconds.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
venv="$root/.venv"
py="${PYTHON:-python3.11}"
stamps="$venv/.stamps"

hash_of() { cat "$@" | sha256sum | cut -c1-16; }
# The machine's pip config may point at local wheel folders that do not exist: silence that noise.
pipq() {
  local rc=0
  "$venv/bin/python" -m pip --disable-pip-version-check -q "$@" > "$venv/.pip.log" 2>&1 || rc=$?
  grep -v "is ignored: it is neither a file nor a directory" "$venv/.pip.log" || true
  return $rc
}

if [ ! -x "$venv/bin/python" ]; then
  echo "[setup] creating .venv with $py"
  "$py" -m venv "$venv"
fi
mkdir -p "$stamps"

req_hash=$(hash_of requirements.txt)
if [ "$(cat "$stamps/requirements" 2>/dev/null)" != "$req_hash" ]; then
  echo "[setup] installing pinned dependencies (requirements.txt)"
  pipq install -r requirements.txt
  "$venv/bin/python" -c "import pinocchio, coal, pybullet, daqp, proxsuite, qpsolvers, rosbags, mcap, yaml" \
    || { echo "[setup] dependency install failed" >&2; exit 1; }
  echo "$req_hash" > "$stamps/requirements"
fi

# The ROS wheels export CMake files that point at the manylinux build interpreter: point them at
# this venv's interpreter and numpy before building interfaces (FIELD_NOTES).
if [ ! -f "$stamps/cmake_paths" ]; then
  echo "[setup] fixing Python include paths in the ROS wheels' CMake files"
  "$venv/bin/python" "$root/scripts/fix_ros_cmake_paths.py" "$venv"
  touch "$stamps/cmake_paths"
fi

msgs_hash=$(hash_of src/climb_msgs/CMakeLists.txt src/climb_msgs/package.xml src/climb_msgs/msg/* src/climb_msgs/srv/* src/climb_msgs/action/*)
if [ "$(cat "$stamps/climb_msgs" 2>/dev/null)" != "$msgs_hash" ]; then
  echo "[setup] building climb_msgs (rosidl) into .venv"
  build="$root/build/climb_msgs"
  rm -rf "$build"; mkdir -p "$build"
  export PATH="$venv/bin:$PATH"
  ( cd "$build" && cmake "$root/src/climb_msgs" -DCMAKE_INSTALL_PREFIX="$venv" -DCMAKE_PREFIX_PATH="$venv" \
      -DPython3_EXECUTABLE="$venv/bin/python" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release > cmake.log 2>&1 \
    && make -j2 > make.log 2>&1 && make install > install.log 2>&1 ) \
    || { echo "[setup] climb_msgs build failed; see $build/*.log" >&2; tail -30 "$build"/*.log >&2; exit 1; }
  "$venv/bin/python" -c "from climb_msgs.msg import Hold, SimContacts; from climb_msgs.srv import Climb; from climb_msgs.action import Climb as ClimbAction" \
    || { echo "[setup] climb_msgs built but does not import" >&2; exit 1; }
  echo "$msgs_hash" > "$stamps/climb_msgs"
fi

pkgs_hash=$(hash_of src/*/setup.py src/*/setup.cfg)
if [ "$(cat "$stamps/packages" 2>/dev/null)" != "$pkgs_hash" ]; then
  echo "[setup] installing the project's Python packages (editable)"
  for p in climb_core msgs_py sim_bridge controller_node planner_node climb_coordinator; do
    pipq install --no-deps --no-build-isolation -e "src/$p"
  done
  echo "$pkgs_hash" > "$stamps/packages"
fi
echo "[setup] ready: $venv"
