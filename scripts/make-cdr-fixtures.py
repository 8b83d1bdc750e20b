#!/usr/bin/env python3
"""Write tests/data/cdr/fixtures.jsonl: messages serialized by a real ROS 2 stack.

Each line is {"type", "message" (the fields, as ferrosa's JSON shows them), "cdr" (hex of
the body after the 4-byte encapsulation header, as rclpy's serialize_message made it)}.
Made with rclpy 7.1.6 (Jazzy, rmw_fastrtps) from PyPI:

    python3 -m venv /tmp/rosvenv
    /tmp/rosvenv/bin/pip install 'ros-rclpy[fastrtps]==7.1.6' 'ros-std-msgs<5.5' \
        'ros-std-srvs<5.5' 'ros-geometry-msgs<5.5' 'ros-sensor-msgs<5.5' \
        'ros-nav-msgs<5.5' 'ros-diagnostic-msgs<5.5'
    /tmp/rosvenv/bin/python scripts/make-cdr-fixtures.py > tests/data/cdr/fixtures.jsonl
"""
import json
import re

from rclpy.serialization import serialize_message
import importlib

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, Twist
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Log, ParameterEvent
from rcl_interfaces.srv import GetParameters, SetParameters
from sensor_msgs.msg import BatteryState, JointState, LaserScan
from std_msgs.msg import Empty, Float32MultiArray, Header, String, UInt8MultiArray
from std_srvs.srv import SetBool, Trigger

CASES = [
    ("std_msgs/msg/String", String, {"data": "hello robot"}),
    ("std_msgs/msg/String", String, {"data": ""}),
    ("std_msgs/msg/Empty", Empty, {}),
    ("std_msgs/msg/Header", Header, {"stamp": {"sec": 1700000000, "nanosec": 5}, "frame_id": "map"}),
    ("std_msgs/msg/UInt8MultiArray", UInt8MultiArray,
     {"layout": {"dim": [{"label": "x", "size": 3, "stride": 3}], "data_offset": 0}, "data": [1, 2, 255]}),
    ("std_msgs/msg/Float32MultiArray", Float32MultiArray, {"data": [0.5, -1.25, 3.0]}),
    ("geometry_msgs/msg/Twist", Twist, {"linear": {"x": 1.5, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": -0.75}}),
    ("geometry_msgs/msg/PoseWithCovarianceStamped", PoseWithCovarianceStamped,
     {"header": {"frame_id": "odom"}, "pose": {"pose": {"position": {"x": 1.0, "y": 2.0}, "orientation": {"w": 1.0}},
                                               "covariance": [float(i) for i in range(36)]}}),
    ("nav_msgs/msg/Odometry", Odometry,
     {"header": {"frame_id": "odom"}, "child_frame_id": "base_link",
      "twist": {"twist": {"linear": {"x": 0.25}}}}),
    ("sensor_msgs/msg/BatteryState", BatteryState,
     {"voltage": 12.5, "percentage": 0.75, "power_supply_status": 2, "present": True,
      "cell_voltage": [4.25, 4.0], "location": "base", "serial_number": "B-1"}),
    ("sensor_msgs/msg/JointState", JointState,
     {"name": ["shoulder", "elbow"], "position": [0.5, -0.25], "velocity": [], "effort": [1.0, 2.0]}),
    ("sensor_msgs/msg/LaserScan", LaserScan,
     {"angle_min": -1.5, "angle_max": 1.5, "range_max": 10.0, "ranges": [1.0, 2.5, 0.25], "intensities": []}),
    ("diagnostic_msgs/msg/DiagnosticArray", DiagnosticArray,
     {"header": {"stamp": {"sec": 3}}, "status": [{"level": b"\x01", "name": "battery", "message": "low",
                                                    "hardware_id": "bat0", "values": [{"key": "pct", "value": "18"}]}]}),
    ("rcl_interfaces/msg/Log", Log,
     {"stamp": {"sec": 10, "nanosec": 20}, "level": 30, "name": "turtlesim", "msg": "hit the wall",
      "file": "sim.rs", "function": "step", "line": 77}),
    ("rcl_interfaces/msg/ParameterEvent", ParameterEvent,
     {"node": "/turtlesim", "changed_parameters": [{"name": "background_r", "value": {"type": 2, "integer_value": 200}}]}),
    ("rcl_interfaces/srv/SetParameters_Request", SetParameters.Request,
     {"parameters": [{"name": "speed", "value": {"type": 3, "double_value": 0.5}},
                     {"name": "mode", "value": {"type": 4, "string_value": "auto"}}]}),
    ("rcl_interfaces/srv/GetParameters_Response", GetParameters.Response,
     {"values": [{"type": 1, "bool_value": True}, {"type": 9, "string_array_value": ["a", "bc"]}]}),
    ("std_srvs/srv/SetBool_Request", SetBool.Request, {"data": True}),
    ("std_srvs/srv/Trigger_Response", Trigger.Response, {"success": True, "message": "done"}),
]


def message_class(type_text):
    """`sequence<pkg/Name>` or `pkg/Name[3]` to the Python class, or None for primitives."""
    m = re.search(r"([a-z0-9_]+)/([A-Za-z0-9]+)", type_text)
    if not m:
        return None
    return getattr(importlib.import_module(m.group(1) + ".msg"), m.group(2))


def set_fields(msg, fields):
    types = msg.get_fields_and_field_types()
    for name, value in fields.items():
        cls = message_class(types[name])
        if cls is not None and isinstance(value, list):
            items = []
            for v in value:
                item = cls()
                set_fields(item, v)
                items.append(item)
            setattr(msg, name, items)
        elif cls is not None:
            set_fields(getattr(msg, name), value)
        else:
            setattr(msg, name, value)


def to_dict(msg):
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: to_dict(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple)) or hasattr(msg, "tolist"):
        return [to_dict(v) for v in (msg.tolist() if hasattr(msg, "tolist") else msg)]
    return msg


def plain(value):
    """rosidl's dict with bytes as numbers and arrays as lists, as ferrosa's JSON has them."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, bytes):
        return value[0] if len(value) == 1 else list(value)
    if hasattr(value, "tolist"):
        return plain(value.tolist())
    return value


for type_name, cls, fields in CASES:
    msg = cls()
    set_fields(msg, fields)
    body = serialize_message(msg)[4:]
    print(json.dumps({"type": type_name, "message": plain(to_dict(msg)), "cdr": body.hex()}))
