#!/usr/bin/env bash
# Build Nav2's message package (nav2_msgs: NavigateToPose) for rclpy, from the definition
# ferrosa bundles (src/ros/interfaces/nav2_msgs.idl), into the rclpy virtualenv of
# .ci/setup: the Nav2 peer of the place tests (tests/peers/nav2_peer.py) serves the
# action with these generated types.
#
# nav2_msgs is not on PyPI, but ROS 2 Jazzy's interface generators are (rosidl and
# ament_cmake, installed by .ci/setup into the same virtualenv), so the package is
# generated the way a ROS workspace would: an ament package with one .action file,
# configured, built and installed with cmake (about 10 s on 2 cores). Constants and
# comments do not enter a type's hash (REP 2011), its fields do: tests/nav2.rs checks
# that the hashes the peer announces are those of Jazzy's nav2_msgs.
#
# Usage: scripts/build-nav2-msgs.sh [VENV]   (default target/rosvenv)
set -euo pipefail
cd "$(dirname "$0")/.."
venv=$(realpath "${1:-target/rosvenv}")
[ -x "$venv/bin/python" ] || { echo "no virtualenv at $venv: run .ci/setup" >&2; exit 1; }
pkg=target/nav2_msgs
rm -rf "$pkg"
mkdir -p "$pkg/action"

# One .action file per `=== nav2_msgs/action/<Name>` section of the bundle.
actions=$(python3 - "$pkg/action" src/ros/interfaces/nav2_msgs.idl <<'EOF'
import pathlib, sys
out, bundle = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]).read_text()
names = []
for section in bundle.split("=== ")[1:]:
    head, _, body = section.partition("\n")
    package, kind, name = head.strip().split("/")
    if package == "nav2_msgs" and kind == "action":
        (out / f"{name}.action").write_text(body)
        names.append(f"action/{name}.action")
print(" ".join(names))
EOF
)
[ -n "$actions" ] || { echo "no nav2_msgs actions in the bundle" >&2; exit 1; }

cat > "$pkg/package.xml" <<'EOF'
<?xml version="1.0"?>
<package format="3">
  <name>nav2_msgs</name>
  <version>1.3.0</version>
  <description>Nav2's actions, generated from ferrosa's bundled definitions for its tests.</description>
  <maintainer email="ferrosa@example.org">ferrosa</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>action_msgs</depend>
  <depend>builtin_interfaces</depend>
  <depend>geometry_msgs</depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
EOF

cat > "$pkg/CMakeLists.txt" <<EOF
cmake_minimum_required(VERSION 3.8)
project(nav2_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(action_msgs REQUIRED)
find_package(builtin_interfaces REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(\${PROJECT_NAME} $actions
  DEPENDENCIES action_msgs builtin_interfaces geometry_msgs)
# The message wheels on PyPI export the include directory of the Python they were built
# with (/opt/python/...); point it at this interpreter's.
get_property(_targets DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_t IN LISTS _targets)
  get_target_property(_inc \${_t} INTERFACE_INCLUDE_DIRECTORIES)
  if(_inc AND "\${_inc}" MATCHES "/opt/python/")
    list(FILTER _inc EXCLUDE REGEX "^/opt/python/")
    list(APPEND _inc \${Python3_INCLUDE_DIRS})
    set_target_properties(\${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "\${_inc}")
  endif()
endforeach()
ament_package()
EOF

export PATH="$venv/bin:$PATH"
cmake -S "$pkg" -B "$pkg/build" -DCMAKE_PREFIX_PATH="$venv" -DCMAKE_INSTALL_PREFIX="$venv" \
    -DPython3_EXECUTABLE="$venv/bin/python3" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF >/dev/null
cmake --build "$pkg/build" -j"$(nproc)" >/dev/null
cmake --install "$pkg/build" >/dev/null
"$venv/bin/python" -c "from nav2_msgs.action import NavigateToPose"
