#!/usr/bin/env python3
"""An independent ROS 2 peer (rclpy, rmw_fastrtps, from PyPI) for ferrosa's interop tests.

    rclpy_peer.py serve   # node /peer: /chatter (std_msgs/String, 10 Hz),
                          # /peer/transition (lifecycle_msgs/TransitionEvent, 10 Hz: a type
                          # ferrosa does not ship), /peer/trigger (std_srvs/Trigger),
                          # /peer/set_flag (std_srvs/SetBool), parameter speed=0.5, and
                          # a subscriber on /peer/command (std_msgs/String) whose messages
                          # /peer/trigger reports; runs until killed
    rclpy_peer.py drive   # finds ferrosa's /turtlesim, sends turtle1 forward at 1 m/s
                          # (10 Hz for 1 s; turtlesim holds the last for 1 s more), calls
                          # /clear; prints one JSON line: nodes, topics, services it saw
    rclpy_peer.py estop   # as a teleop's e-stop button: once ferrosa follows
                          # /ferrosa/estop, publishes false, then true (std_msgs/Bool,
                          # 100 Hz for 0.3 s); prints one JSON line with the wall-clock
                          # time of the first true
"""
import json
import sys
import time

import rclpy
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger


def serve():
    node = Node("peer")
    node.declare_parameter("speed", 0.5)
    from lifecycle_msgs.msg import State, Transition, TransitionEvent

    pub = node.create_publisher(String, "/chatter", 10)
    events = node.create_publisher(TransitionEvent, "/peer/transition", 10)
    count = [0]
    flag = [False]
    commands = []

    def command(msg):
        commands.append(msg.data)

    node.create_subscription(String, "/peer/command", command, 10)

    def tick():
        count[0] += 1
        pub.publish(String(data=f"hello {count[0]}"))
        events.publish(TransitionEvent(
            timestamp=count[0],
            transition=Transition(id=Transition.TRANSITION_CONFIGURE, label="configure"),
            start_state=State(id=State.PRIMARY_STATE_UNCONFIGURED, label="unconfigured"),
            goal_state=State(id=State.PRIMARY_STATE_INACTIVE, label="inactive"),
        ))

    def trigger(_req, resp):
        resp.success = True
        resp.message = f"triggered after {count[0]} messages; commands: {commands}"
        return resp

    def set_flag(req, resp):
        flag[0] = req.data
        resp.success = True
        resp.message = f"flag is {flag[0]}"
        return resp

    node.create_timer(0.1, tick)
    node.create_service(Trigger, "/peer/trigger", trigger)
    node.create_service(SetBool, "/peer/set_flag", set_flag)
    print("peer ready", flush=True)
    rclpy.spin(node)


def drive():
    # turtlesim's Python types are not on PyPI: drive with geometry_msgs and std_srvs only;
    # the test reads the pose from the sim itself.
    from geometry_msgs.msg import Twist
    from std_srvs.srv import Empty

    node = Node("driver")
    deadline = time.time() + 20
    while time.time() < deadline and "/turtlesim" not in _nodes(node):
        rclpy.spin_once(node, timeout_sec=0.1)
    pub = node.create_publisher(Twist, "/turtle1/cmd_vel", 10)
    while time.time() < deadline and pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.1)
    topics = {n: t for n, t in node.get_topic_names_and_types()}
    services = {n: t for n, t in node.get_service_names_and_types()}
    # As a teleop does: 1 m/s at 10 Hz for one second. A single message sent the moment
    # the subscription matched is sometimes lost on the RustDDS side.
    msg = Twist()
    msg.linear.x = 1.0
    for _ in range(10):
        pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=0.1)
    clear = node.create_client(Empty, "/clear")
    cleared = clear.wait_for_service(timeout_sec=5.0)
    if cleared:
        future = clear.call_async(Empty.Request())
        rclpy.spin_until_future_complete(node, future, timeout_sec=5.0)
        cleared = future.done()
    print(json.dumps({"nodes": _nodes(node), "topics": topics, "services": services,
                      "subscribers": pub.get_subscription_count(), "cleared": cleared}), flush=True)


def estop():
    from std_msgs.msg import Bool

    node = Node("estop_button")
    pub = node.create_publisher(Bool, "/ferrosa/estop", 10)
    deadline = time.time() + 20
    while time.time() < deadline and pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    matched = pub.get_subscription_count()
    # As a button's state topic does: released, then pressed. The first publish also
    # warms rclpy's type support up, so the press below is timed on its own.
    pub.publish(Bool(data=False))
    time.sleep(0.2)
    first = time.time()
    for _ in range(30):
        pub.publish(Bool(data=True))
        time.sleep(0.01)
    print(json.dumps({"published_at": first, "subscribers": matched}), flush=True)


def _nodes(node):
    return sorted(("/" + ns.strip("/") + "/" + n).replace("//", "/") for n, ns in node.get_node_names_and_namespaces())


if __name__ == "__main__":
    rclpy.init()
    {"serve": serve, "drive": drive, "estop": estop}[sys.argv[1]]()
