#!/usr/bin/env python3
"""Write src/ros/interfaces/<package>.idl from an installed ROS 2 share/ tree.

Each bundle holds the package's .msg/.srv/.action definitions with comments and blank
lines removed, one section per type headed `=== <pkg>/<kind>/<Name>`. Made with the Jazzy
message packages from PyPI:

    python3 -m venv /tmp/rosvenv
    /tmp/rosvenv/bin/pip install 'ros-rclpy[fastrtps]==7.1.6' 'ros-std-msgs<5.5' \
        'ros-std-srvs<5.5' 'ros-geometry-msgs<5.5' 'ros-sensor-msgs<5.5' \
        'ros-nav-msgs<5.5' 'ros-diagnostic-msgs<5.5'
    python3 scripts/bundle-interfaces.py /tmp/rosvenv/share src/ros/interfaces [PKG...]

With package names after the two paths, only those are written (the others stay as they
are); type_description_interfaces comes with rclpy itself.
"""
import pathlib
import sys

PACKAGES = [
    "action_msgs", "builtin_interfaces", "diagnostic_msgs", "geometry_msgs", "nav_msgs",
    "rcl_interfaces", "rosgraph_msgs", "sensor_msgs", "std_msgs", "std_srvs",
    "unique_identifier_msgs", "type_description_interfaces",
]


def strip(text):
    out = []
    for line in text.splitlines():
        if line.strip() == "---":
            out.append("---")
            continue
        code = line.split("#", 1)[0].rstrip() if not _in_string(line) else line.rstrip()
        if code.strip():
            out.append(" ".join(code.split()))
    return out


def _in_string(line):
    # `string NAME="a#b"` keeps its '#': only a constant or default with quotes.
    head = line.split("#", 1)[0]
    return head.count('"') % 2 == 1 or head.count("'") % 2 == 1


def main(share, dest, *only):
    share, dest = pathlib.Path(share), pathlib.Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    for pkg in only or PACKAGES:
        sections = []
        for kind in ("msg", "srv", "action"):
            for path in sorted((share / pkg / kind).glob(f"*.{kind}")):
                body = strip(path.read_text())
                sections.append(f"=== {pkg}/{kind}/{path.stem}\n" + "".join(l + "\n" for l in body))
        (dest / f"{pkg}.idl").write_text("".join(sections))
        print(pkg, len(sections))


if __name__ == "__main__":
    main(*sys.argv[1:])
