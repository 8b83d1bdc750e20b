#!/usr/bin/env python3
"""The faults of ferrosa's soak (tests/soak.rs): foreign ROS 2 nodes (rclpy, rmw_fastrtps,
from PyPI) that misbehave as peers on a robot do. Each prints "ready <pid>" on stdout once
its endpoints exist; the test stops it by that pid.

    soak_peer.py serve       # node /soak_peer: /soak_peer/trigger (std_srvs/Trigger,
                             # answers at once), /soak_peer/slow (std_srvs/Trigger: prints
                             # "slow call" and answers only after 30 s; the test kills the
                             # process in between), parameter gain=0.5
    soak_peer.py hang        # node /soak_hang: /soak_hang/trigger (std_srvs/Trigger) never
                             # answers (its one executor thread sleeps in the first call)
    soak_peer.py flood HZ    # node /soak_flood: /soak/flood (std_msgs/String, 200 bytes)
                             # and /ferrosa/estop (std_msgs/Bool, false: a node that
                             # floods the e-stop topic without pressing it), each at HZ
                             # messages a second, until killed
    soak_peer.py press       # a teleop's e-stop button: once ferrosa follows
                             # /ferrosa/estop it is ready; at a line on stdin it publishes
                             # true (100 Hz for 0.3 s) and prints "pressed <subscribers>"
"""
import os
import sys
import time

import rclpy
from rclpy.node import Node
from std_srvs.srv import Trigger


def ready():
    print(f"ready {os.getpid()}", flush=True)


def serve():
    node = Node("soak_peer")
    node.declare_parameter("gain", 0.5)
    calls = [0]

    def trigger(_req, resp):
        calls[0] += 1
        resp.success = True
        resp.message = f"triggered {calls[0]}"
        return resp

    def slow(_req, resp):
        print("slow call", flush=True)
        time.sleep(30)
        resp.success = True
        resp.message = "late"
        return resp

    node.create_service(Trigger, "/soak_peer/trigger", trigger)
    node.create_service(Trigger, "/soak_peer/slow", slow)
    ready()
    rclpy.spin(node)


def hang():
    node = Node("soak_hang")

    def never(_req, resp):
        while True:
            time.sleep(3600)

    node.create_service(Trigger, "/soak_hang/trigger", never)
    ready()
    rclpy.spin(node)


def flood(hz):
    from std_msgs.msg import Bool, String

    node = Node("soak_flood")
    text = node.create_publisher(String, "/soak/flood", 10)
    estop = node.create_publisher(Bool, "/ferrosa/estop", 10)
    ready()
    period = 1.0 / hz
    pad = "x" * 190
    n = 0
    next_at = time.monotonic()
    while rclpy.ok():
        n += 1
        text.publish(String(data=f"{n:09d}{pad}"))
        estop.publish(Bool(data=False))
        next_at += period
        lag = next_at - time.monotonic()
        if lag > 0:
            time.sleep(lag)
        elif lag < -1.0:
            # Behind by a second: the machine is busy; drop the backlog, keep the rate.
            next_at = time.monotonic()


def press():
    from std_msgs.msg import Bool

    node = Node("soak_button")
    pub = node.create_publisher(Bool, "/ferrosa/estop", 10)
    deadline = time.time() + 20
    while time.time() < deadline and pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    matched = pub.get_subscription_count()
    ready()
    sys.stdin.readline()
    for _ in range(30):
        pub.publish(Bool(data=True))
        time.sleep(0.01)
    print(f"pressed {matched}", flush=True)


if __name__ == "__main__":
    rclpy.init()
    mode = sys.argv[1]
    if mode == "flood":
        flood(float(sys.argv[2]))
    else:
        {"serve": serve, "hang": hang, "press": press}[mode]()
