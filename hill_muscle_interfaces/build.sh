#!/usr/bin/env bash
# Build and install hill_muscle_interfaces (an ament_cmake interface package)
# against the ROS 2 Jazzy PyPI wheels of a virtual environment, as a plain user.
#
#   hill_muscle_interfaces/build.sh VENV_BIN PREFIX [BUILD_DIR]
#
# VENV_BIN  the venv's bin directory (VENV_BIN/python is used); the venv holds
#           ../requirements-ros.txt and requirements-build.txt.
# PREFIX    the install prefix (created if missing).
# BUILD_DIR the CMake build tree, thrown away on every rebuild; default
#           ${TMPDIR:-/tmp}/hill_muscle_interfaces-build-<uid>-<hash of PREFIX>.
#
# Idempotent: PREFIX/share/hill_muscle_interfaces/build.stamp records a hash of
# the sources, this script, the interpreter, the prefix and the installed ROS
# wheels' versions; when it matches, nothing is done. JOBS sets the build's
# parallel jobs (default 1). Writes only under BUILD_DIR and PREFIX; needs no
# root. Runs with AMENT_PREFIX_PATH and CMAKE_PREFIX_PATH set to the venv alone
# and PYTHONPATH unset, so a sourced /opt/ros install cannot mix in.
#
# To use the result (also printed at the end, and written to PREFIX/env.sh):
#   export PYTHONPATH=PREFIX/lib/python3.X/site-packages
#   export LD_LIBRARY_PATH=PREFIX/lib      (set before Python starts)
#   export AMENT_PREFIX_PATH=PREFIX:VENV
# With PREFIX the venv itself (build.sh .venv/bin .venv), none of them is
# needed: the venv's site-packages is on sys.path and the wheels' start-up hook
# puts VENV/lib on LD_LIBRARY_PATH.
set -euo pipefail

usage() {
    echo "usage: $0 VENV_BIN PREFIX [BUILD_DIR]" >&2
    exit 2
}
[ $# -ge 2 ] && [ $# -le 3 ] || usage

die() {
    echo "build.sh: $*" >&2
    exit 1
}

SRC=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
PKG=hill_muscle_interfaces
PY=$1/python
[ -x "$PY" ] || die "no python in $1"
JOBS=${JOBS:-1}

for tool in cmake cc c++ sha256sum flock; do
    command -v "$tool" >/dev/null || die "$tool not found on PATH"
done

# The venv's prefix, where the wheels put share/<pkg>/cmake and the ament index.
# PYTHONPATH is unset for every Python and CMake run of this script.
run() { env -u PYTHONPATH "$@"; }
VENV=$(run "$PY" -c 'import sys; print(sys.prefix)')
PYVER=$(run "$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
# What requirements-build.txt brings (the wheels do not all declare each other).
for dep in ament_cmake ament_cmake_include_directories ament_cmake_ros ament_cmake_gmock \
        ament_cmake_gtest ament_cmake_pytest python_cmake_module rosidl_default_generators \
        rosidl_core_generators std_msgs; do
    [ -f "$VENV/share/$dep/cmake/${dep}Config.cmake" ] ||
        die "$VENV has no $dep: pip install -r requirements-ros.txt -r $PKG/requirements-build.txt into it"
done
run "$PY" -c 'import ament_package, catkin_pkg' 2>/dev/null ||
    die "$PY cannot import ament_package and catkin_pkg: pip install -r $PKG/requirements-build.txt"
run "$PY" -c 'import os, sys, sysconfig
sys.exit(not os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' ||
    die "no Python.h for $PY (on Debian/Ubuntu: the python$PYVER-dev package)"

mkdir -p "$2"
PREFIX=$(cd "$2" && pwd)

# PREFIX may be the venv itself: then nothing is needed to use the package.
IN_VENV=false
[ "$(cd "$PREFIX" && pwd -P)" = "$(cd "$VENV" && pwd -P)" ] && IN_VENV=true

STAMP_DIR=$PREFIX/share/$PKG
STAMP=$STAMP_DIR/build.stamp
BUILD=${3:-${TMPDIR:-/tmp}/$PKG-build-$(id -u)-$(printf '%s' "$PREFIX" | sha256sum | cut -c1-12)}

# One build at a time per prefix.
mkdir -p "$STAMP_DIR"
exec 9>"$STAMP_DIR/.build.lock"
flock 9

inputs_hash() {
    {
        (cd "$SRC" && sha256sum CMakeLists.txt package.xml msg/*.msg cmake/*.cmake build.sh)
        echo "python $(readlink -f "$PY") $PYVER"
        echo "venv $VENV"
        echo "prefix $PREFIX"
        cmake --version | sed -n 1p
        # The installed wheels' names and versions (ros_*, catkin_pkg, numpy).
        (cd "$VENV"/lib/python"$PYVER"/site-packages &&
            ls -d ros_*.dist-info catkin_pkg*.dist-info numpy*.dist-info 2>/dev/null || true) | sort
    } | sha256sum | cut -d' ' -f1
}

site_packages() {
    # Where ament_cmake_python installed the Python package.
    local dir
    for dir in "$PREFIX"/lib/python"$PYVER"/site-packages "$PREFIX"/local/lib/python"$PYVER"/dist-packages; do
        if [ -d "$dir/$PKG" ]; then
            echo "$dir"
            return 0
        fi
    done
    return 1
}

HASH=$(inputs_hash)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$HASH" ] && site_packages >/dev/null; then
    echo "build.sh: $PKG is up to date in $PREFIX"
    exit 0
fi
rm -f "$STAMP"

export AMENT_PREFIX_PATH=$VENV
export CMAKE_PREFIX_PATH=$VENV

t0=$SECONDS
rm -rf "$BUILD"
run cmake -S "$SRC" -B "$BUILD" \
    -DCMAKE_INSTALL_PREFIX="$PREFIX" \
    -DCMAKE_PREFIX_PATH="$VENV" \
    -DPython3_EXECUTABLE="$PY" \
    -DCMAKE_BUILD_TYPE=Release \
    -DBUILD_TESTING=OFF \
    -DCMAKE_PROJECT_INCLUDE="$SRC/cmake/pypi_wheel_fixups.cmake"
t1=$SECONDS
run cmake --build "$BUILD" -j "$JOBS"
t2=$SECONDS
run cmake --install "$BUILD"
t3=$SECONDS

SITE=$(site_packages) || die "the install put no $PKG Python package under $PREFIX"

# The installed message imports, and survives a CDR round trip (no DDS traffic).
env -u PYTHONPATH -u _ROS_WHEELS_BOOTSTRAP_COMPLETE PYTHONPATH="$SITE" \
    LD_LIBRARY_PATH="$PREFIX/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" \
    AMENT_PREFIX_PATH="$PREFIX:$VENV" "$PY" -c '
from rclpy.serialization import deserialize_message, serialize_message
from hill_muscle_interfaces.msg import Stimulation
m = Stimulation(channel=[1, 2], mode=["single", "doublet"], pulse_width_s=[3e-4, 3e-4],
                current_a=[], frequency_hz=[30.0, 30.0])
assert deserialize_message(serialize_message(m), Stimulation) == m
' || die "the installed $PKG does not import or round-trip"

if ! $IN_VENV; then
    cat >"$PREFIX/env.sh" <<EOF
# Generated by $PKG/build.sh: source it before starting Python.
export PYTHONPATH="$SITE\${PYTHONPATH:+:\$PYTHONPATH}"
export LD_LIBRARY_PATH="$PREFIX/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
export AMENT_PREFIX_PATH="$PREFIX:$VENV\${AMENT_PREFIX_PATH:+:\$AMENT_PREFIX_PATH}"
EOF
fi
echo "$HASH" >"$STAMP"

echo "build.sh: built $PKG into $PREFIX (configure $((t1 - t0)) s, build $((t2 - t1)) s, install $((t3 - t2)) s)"
if $IN_VENV; then
    # The venv's site-packages is on sys.path, and the wheels' start-up hook
    # (ros_wheels_bootstrapper) puts VENV/lib on LD_LIBRARY_PATH.
    echo "build.sh: installed into the venv itself: $PY needs no environment variables"
else
    echo "build.sh: to use it, . $PREFIX/env.sh  (or set:)"
    echo "  PYTHONPATH=$SITE"
    echo "  LD_LIBRARY_PATH=$PREFIX/lib"
    echo "  AMENT_PREFIX_PATH=$PREFIX:$VENV"
fi
