#!/usr/bin/env python3
"""The project's second robot: a 6-joint arm with a two-finger gripper and a wrist
force/torque sensor, as its vendor's ROS 2 driver would present it (rclpy, rmw_fastrtps,
from PyPI). Its state is simulated but real to the graph: commands move the joints over
time and every topic reads the new state back.

    arm_peer.py serve   # runs until killed; prints "arm ready" once serving

Nodes, and what each offers (types are the standard ROS 2 ones ferrosa ships):

/arm_controller
  publishes  /joint_states       sensor_msgs/msg/JointState      25 Hz  rad, rad/s, N m
             /arm/tcp_pose       geometry_msgs/msg/PoseStamped   25 Hz  tool0 in base_link
             /arm/state          std_msgs/msg/String              2 Hz  "idle at home", ...
             /diagnostics        diagnostic_msgs/msg/DiagnosticArray 1 Hz  per joint motor
  subscribes /arm/named_pose_cmd std_msgs/msg/String              a named pose to go to
             /arm/joint_command  std_msgs/msg/Float64MultiArray   6 joint targets in rad
  services   /arm/go_home        std_srvs/srv/Trigger
             /arm/stop           std_srvs/srv/Trigger             halt, hold position
             /arm/enable_motors  std_srvs/srv/SetBool             false: brakes on
  parameters joint_names, named_poses, base_frame, tool_frame (read-only),
             max_joint_velocity (rad/s), velocity_scaling (0-1), payload_kg (0-5)
/gripper_driver
  publishes  /gripper/state      sensor_msgs/msg/JointState      10 Hz  gripper_finger_joint:
                                 position = opening in m (0 closed, 0.085 open),
                                 effort = grip force in N
  services   /gripper/open, /gripper/close   std_srvs/srv/Trigger
  parameters max_width (m, read-only), grip_force (N, 20-140)
/ft_sensor
  publishes  /ft_sensor/wrench   geometry_msgs/msg/WrenchStamped 50 Hz  N, N m
  services   /ft_sensor/zero     std_srvs/srv/Trigger             bias the readings to zero
  parameters frame_id (read-only), rate_hz (read-only)

No action: the arm's natural one (control_msgs/action/FollowJointTrajectory) is not on
PyPI, and no installable ROS 2 action type fits an arm.
"""
import math
import random
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
          "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
# Joint limits in rad (the elbow's cable routing allows half a turn each way).
LIMITS = [(-6.28, 6.28), (-6.28, 6.28), (-3.14, 3.14), (-6.28, 6.28), (-6.28, 6.28), (-6.28, 6.28)]
POSES = {
    "home": [0.0, -1.571, 1.571, -1.571, -1.571, 0.0],
    "ready": [0.0, -1.1, 1.9, -2.37, -1.571, 0.0],
    "pick": [0.6, -0.75, 1.65, -2.47, -1.571, 0.6],
    "stow": [0.0, -2.9, 2.75, -1.42, -1.571, 0.0],
}
# Standard DH parameters of the arm (m, rad): a, d, alpha per joint.
DH = [(0.0, 0.1625, math.pi / 2), (-0.425, 0.0, 0.0), (-0.3922, 0.0, 0.0),
      (0.0, 0.1333, math.pi / 2), (0.0, 0.0997, -math.pi / 2), (0.0, 0.0996, 0.0)]
# Each motor's temperature at rest, deg C; the elbow's runs warm (a WARN at 60).
MOTOR_TEMP = [36.5, 44.0, 61.5, 39.0, 37.5, 35.0]
TEMP_WARN, TEMP_ERROR = 60.0, 75.0
GRIPPER_MAX = 0.085
GRIPPER_SPEED = 0.15  # m/s


def now_msg(node):
    return node.get_clock().now().to_msg()


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def forward_kinematics(q):
    """tool0's position and orientation (quaternion x, y, z, w) in base_link."""
    t = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for theta, (a, d, alpha) in zip(q, DH):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        t = matmul(t, [[ct, -st * ca, st * sa, a * ct],
                       [st, ct * ca, -ct * sa, a * st],
                       [0.0, sa, ca, d],
                       [0.0, 0.0, 0.0, 1.0]])
    r = t
    trace = r[0][0] + r[1][1] + r[2][2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        quat = ((r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, s / 4)
    elif r[0][0] > r[1][1] and r[0][0] > r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[0][0] - r[1][1] - r[2][2])
        quat = (s / 4, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s, (r[2][1] - r[1][2]) / s)
    elif r[1][1] > r[2][2]:
        s = 2.0 * math.sqrt(1.0 + r[1][1] - r[0][0] - r[2][2])
        quat = ((r[0][1] + r[1][0]) / s, s / 4, (r[1][2] + r[2][1]) / s, (r[0][2] - r[2][0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2][2] - r[0][0] - r[1][1])
        quat = ((r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, s / 4, (r[1][0] - r[0][1]) / s)
    return (t[0][3], t[1][3], t[2][3]), quat


def ranged(description, low, high, read_only=False):
    return ParameterDescriptor(
        description=description, read_only=read_only,
        floating_point_range=[FloatingPointRange(from_value=low, to_value=high, step=0.0)])


def fixed(description):
    return ParameterDescriptor(description=description, read_only=True)


class Arm:
    """The arm's joints: where they are, where they are going, and how."""

    def __init__(self, node):
        self.node = node
        self.q = list(POSES["home"])
        self.qd = [0.0] * 6
        self.start = list(self.q)
        self.goal = None  # (target, t0, duration)
        self.target_name = "home"
        self.enabled = True
        self.state = "idle at home"
        self.moves = 0

    def log(self):
        return self.node.get_logger()

    def speed(self):
        p = self.node.get_parameter
        return max(1e-3, p("max_joint_velocity").value * p("velocity_scaling").value)

    def move_to(self, target, name):
        """Start a move; an error message, or None when it started."""
        if not self.enabled:
            return "motors are disabled; call /arm/enable_motors with true first"
        if len(target) != 6:
            return f"need 6 joint positions, got {len(target)}"
        for j, (v, (lo, hi)) in enumerate(zip(target, LIMITS)):
            if not (lo <= v <= hi) or math.isnan(v):
                return f"{JOINTS[j]} target {v:.3f} rad is outside its limits [{lo}, {hi}]"
        span = max(abs(t - c) for t, c in zip(target, self.q))
        duration = max(0.3, span / self.speed())
        self.start = list(self.q)
        self.goal = (list(target), time.monotonic(), duration)
        self.target_name = name
        self.state = f"moving to {name}"
        self.moves += 1
        self.log().info(f"moving to {name} in {duration:.1f} s")
        return None

    def halt(self, why):
        was_moving = self.goal is not None
        self.goal = None
        self.qd = [0.0] * 6
        self.state = why
        return was_moving

    def step(self):
        if self.goal is None:
            self.qd = [0.0] * 6
            return
        target, t0, duration = self.goal
        s = min(1.0, (time.monotonic() - t0) / duration)
        # A smooth profile: zero velocity at both ends.
        blend = 3 * s * s - 2 * s * s * s
        dblend = (6 * s - 6 * s * s) / duration
        self.q = [a + (b - a) * blend for a, b in zip(self.start, target)]
        self.qd = [(b - a) * dblend for a, b in zip(self.start, target)]
        if s >= 1.0:
            self.q = list(target)
            self.qd = [0.0] * 6
            self.goal = None
            named = self.target_name if self.target_name in POSES else None
            self.state = f"idle at {named}" if named else "idle"
            self.log().info(f"reached {self.target_name}")

    def efforts(self):
        payload = self.node.get_parameter("payload_kg").value
        q = self.q
        lift = 9.81 * ((3.7 + payload) * 0.425 * math.cos(q[1]) + (1.2 + payload) * 0.39 * math.cos(q[1] + q[2]))
        elbow = 9.81 * (1.2 + payload) * 0.39 * math.cos(q[1] + q[2])
        wrist = 9.81 * (1.0 + payload) * 0.1 * math.cos(q[1] + q[2] + q[3])
        return [0.0, round(lift, 3), round(elbow, 3), round(wrist, 3), 0.0, 0.0]


def arm_controller():
    node = Node("arm_controller")
    node.declare_parameter("joint_names", JOINTS, fixed("The arm's joints, base to flange."))
    node.declare_parameter("named_poses", list(POSES), fixed("Poses /arm/named_pose_cmd accepts."))
    node.declare_parameter("base_frame", "base_link", fixed("The frame /arm/tcp_pose is given in."))
    node.declare_parameter("tool_frame", "tool0", fixed("The tool flange frame."))
    node.declare_parameter("max_joint_velocity", 1.0, ranged("Fastest joint speed, rad/s.", 0.1, 3.14))
    node.declare_parameter("velocity_scaling", 0.5, ranged("Fraction of max_joint_velocity used.", 0.05, 1.0))
    node.declare_parameter("payload_kg", 0.5, ranged("Mass held at the tool, kg.", 0.0, 5.0))
    arm = Arm(node)

    joints = node.create_publisher(JointState, "/joint_states", 10)
    tcp = node.create_publisher(PoseStamped, "/arm/tcp_pose", 10)
    status = node.create_publisher(String, "/arm/state", 10)
    diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", 10)

    def tick():
        arm.step()
        stamp = now_msg(node)
        msg = JointState()
        msg.header.stamp = stamp
        msg.header.frame_id = ""
        msg.name = list(JOINTS)
        msg.position = [round(v, 4) for v in arm.q]
        msg.velocity = [round(v, 4) for v in arm.qd]
        msg.effort = arm.efforts()
        joints.publish(msg)
        (x, y, z), (qx, qy, qz, qw) = forward_kinematics(arm.q)
        pose = PoseStamped()
        pose.header.stamp = stamp
        pose.header.frame_id = "base_link"
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (round(x, 4), round(y, 4), round(z, 4))
        pose.pose.orientation.x, pose.pose.orientation.y = round(qx, 4), round(qy, 4)
        pose.pose.orientation.z, pose.pose.orientation.w = round(qz, 4), round(qw, 4)
        tcp.publish(pose)

    def publish_state():
        status.publish(String(data=arm.state))

    def publish_diagnostics():
        msg = DiagnosticArray()
        msg.header.stamp = now_msg(node)
        moving = arm.goal is not None
        for j, name in enumerate(JOINTS):
            temp = MOTOR_TEMP[j] + (1.5 if moving else 0.0) + random.uniform(-0.2, 0.2)
            current = abs(arm.efforts()[j]) / 12.0 + (0.4 if moving else 0.05)
            if temp >= TEMP_ERROR:
                level, text = DiagnosticStatus.ERROR, f"motor overheating ({temp:.1f} C)"
            elif temp >= TEMP_WARN:
                level, text = DiagnosticStatus.WARN, f"motor temperature high ({temp:.1f} C, warn at {TEMP_WARN:.0f} C)"
            else:
                level, text = DiagnosticStatus.OK, "OK"
            msg.status.append(DiagnosticStatus(
                level=level, name=f"arm_controller: {name} motor", message=text, hardware_id="arm",
                values=[KeyValue(key="temperature_c", value=f"{temp:.1f}"),
                        KeyValue(key="current_a", value=f"{current:.2f}"),
                        KeyValue(key="position_rad", value=f"{arm.q[j]:.3f}")]))
        msg.status.append(DiagnosticStatus(
            level=DiagnosticStatus.OK if arm.enabled else DiagnosticStatus.WARN,
            name="arm_controller: controller",
            message="motors enabled" if arm.enabled else "motors disabled (brakes on)",
            hardware_id="arm",
            values=[KeyValue(key="state", value=arm.state), KeyValue(key="moves", value=str(arm.moves))]))
        diagnostics.publish(msg)

    def named_pose(msg):
        name = msg.data.strip().lower()
        if name not in POSES:
            node.get_logger().error(f"unknown named pose '{msg.data}'; known: {', '.join(POSES)}")
            return
        err = arm.move_to(POSES[name], name)
        if err:
            node.get_logger().error(f"{name}: {err}")

    def joint_command(msg):
        err = arm.move_to([float(v) for v in msg.data], "joint command")
        if err:
            node.get_logger().error(f"joint command refused: {err}")

    def go_home(_req, resp):
        err = arm.move_to(POSES["home"], "home")
        resp.success = err is None
        resp.message = err or "moving to home"
        return resp

    def stop(_req, resp):
        was_moving = arm.halt("stopped")
        node.get_logger().warn("stop requested: holding position")
        resp.success = True
        resp.message = "stopped; holding position" if was_moving else "already still; holding position"
        return resp

    def enable(req, resp):
        arm.enabled = bool(req.data)
        if not arm.enabled:
            arm.halt("motors disabled")
        else:
            arm.state = "idle"
        node.get_logger().info("motors enabled" if arm.enabled else "motors disabled, brakes on")
        resp.success = True
        resp.message = "motors enabled" if arm.enabled else "motors disabled, brakes on"
        return resp

    node.create_subscription(String, "/arm/named_pose_cmd", named_pose, 10)
    node.create_subscription(Float64MultiArray, "/arm/joint_command", joint_command, 10)
    node.create_service(Trigger, "/arm/go_home", go_home)
    node.create_service(Trigger, "/arm/stop", stop)
    node.create_service(SetBool, "/arm/enable_motors", enable)
    node.create_timer(1 / 25, tick)
    node.create_timer(0.5, publish_state)
    node.create_timer(1.0, publish_diagnostics)
    return node


def gripper_driver():
    node = Node("gripper_driver")
    node.declare_parameter("max_width", GRIPPER_MAX, fixed("Fully open, m."))
    node.declare_parameter("grip_force", 40.0, ranged("Force when closed on an object, N.", 20.0, 140.0))
    state = {"width": GRIPPER_MAX, "target": GRIPPER_MAX, "speed": 0.0}
    pub = node.create_publisher(JointState, "/gripper/state", 10)
    period = 0.1

    def tick():
        diff = state["target"] - state["width"]
        step = GRIPPER_SPEED * period
        if abs(diff) <= step:
            state["width"], state["speed"] = state["target"], 0.0
        else:
            state["width"] += math.copysign(step, diff)
            state["speed"] = math.copysign(GRIPPER_SPEED, diff)
        closed = state["target"] == 0.0 and state["width"] == 0.0
        msg = JointState()
        msg.header.stamp = now_msg(node)
        msg.name = ["gripper_finger_joint"]
        msg.position = [round(state["width"], 4)]
        msg.velocity = [round(state["speed"], 4)]
        msg.effort = [float(node.get_parameter("grip_force").value) if closed else 0.0]
        pub.publish(msg)

    def move(target, word):
        def serve(_req, resp):
            state["target"] = target
            node.get_logger().info(f"gripper {word}")
            resp.success = True
            resp.message = f"gripper {word} to {target:.3f} m"
            return resp
        return serve

    node.create_service(Trigger, "/gripper/open", move(GRIPPER_MAX, "opening"))
    node.create_service(Trigger, "/gripper/close", move(0.0, "closing"))
    node.create_timer(period, tick)
    return node


def ft_sensor():
    node = Node("ft_sensor")
    node.declare_parameter("frame_id", "ft_sensor_link", fixed("The frame of the wrench."))
    node.declare_parameter("rate_hz", 50.0, fixed("Publishing rate."))
    # The gripper's weight on the sensor, and the sensor's own offset: what zeroing removes.
    raw = {"force": (0.8, -0.35, -9.6), "torque": (0.02, 0.11, -0.004)}
    bias = {"force": (0.0, 0.0, 0.0), "torque": (0.0, 0.0, 0.0)}
    pub = node.create_publisher(WrenchStamped, "/ft_sensor/wrench", 10)

    def tick():
        msg = WrenchStamped()
        msg.header.stamp = now_msg(node)
        msg.header.frame_id = "ft_sensor_link"
        f = [v - b + random.gauss(0, 0.03) for v, b in zip(raw["force"], bias["force"])]
        t = [v - b + random.gauss(0, 0.001) for v, b in zip(raw["torque"], bias["torque"])]
        msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = (round(v, 3) for v in f)
        msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = (round(v, 4) for v in t)
        pub.publish(msg)

    def zero(_req, resp):
        bias["force"], bias["torque"] = raw["force"], raw["torque"]
        node.get_logger().info("force/torque sensor zeroed")
        resp.success = True
        resp.message = "sensor zeroed"
        return resp

    node.create_service(Trigger, "/ft_sensor/zero", zero)
    node.create_timer(1 / 50, tick)
    return node


def serve():
    # rclpy refuses a parameter value outside its descriptor's range by itself.
    nodes = [arm_controller(), gripper_driver(), ft_sensor()]
    executor = SingleThreadedExecutor()
    for n in nodes:
        executor.add_node(n)
    print("arm ready", flush=True)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


if __name__ == "__main__":
    rclpy.init()
    {"serve": serve}[sys.argv[1]]()
