"""A Nav2 navigator over rclpy, for tests/nav2.rs: `/navigate_to_pose` served by a node
named bt_navigator with nav2_msgs' generated types (scripts/build-nav2-msgs.sh builds
them into the rclpy virtualenv), and the robot's pose on `/amcl_pose` in `map`.

The robot starts at the map's origin and drives straight to each goal at SPEED m/s,
sending feedback (its pose, the distance remaining, the times) every TICK s. A goal in a
frame other than `map` is rejected, as Nav2 rejects a goal it cannot transform. A cancel
request is accepted and stops the robot where it is.

Everything that reaches the navigator is printed as one JSON line on stdout (`goal`,
`rejected`, `feedback`, `cancel_requested`, `canceled`, `succeeded`), so the test reads
the wire from this side. Runs until killed.

    python tests/peers/nav2_peer.py
"""
import json
import math
import sys
import time

import rclpy
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav2_msgs.action import NavigateToPose
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node

SPEED = 1.0
TICK = 0.1
ARRIVED = 0.05


def say(**event):
    print(json.dumps(event), flush=True)


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class Navigator(Node):
    def __init__(self):
        super().__init__("bt_navigator")
        self.x, self.y, self.yaw = 0.0, 0.0, 0.0
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, "/amcl_pose", 10)
        self.create_timer(0.2, self.publish_pose)
        self.server = ActionServer(
            self,
            NavigateToPose,
            "/navigate_to_pose",
            execute_callback=self.execute,
            goal_callback=self.on_goal,
            cancel_callback=self.on_cancel,
            callback_group=ReentrantCallbackGroup(),
        )

    def stamped(self):
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "map"
        msg.header.stamp = self.get_clock().now().to_msg()
        p = msg.pose.pose
        p.position.x, p.position.y = self.x, self.y
        p.orientation.z, p.orientation.w = math.sin(self.yaw / 2), math.cos(self.yaw / 2)
        return msg

    def publish_pose(self):
        self.pose_pub.publish(self.stamped())

    def on_goal(self, goal):
        pose = goal.pose
        event = dict(
            frame=pose.header.frame_id,
            x=pose.pose.position.x,
            y=pose.pose.position.y,
            yaw=yaw_of(pose.pose.orientation),
            behavior_tree=goal.behavior_tree,
        )
        if pose.header.frame_id != "map":
            say(event="rejected", **event)
            return GoalResponse.REJECT
        say(event="goal", **event)
        return GoalResponse.ACCEPT

    def on_cancel(self, _):
        say(event="cancel_requested", x=self.x, y=self.y)
        return CancelResponse.ACCEPT

    def execute(self, handle):
        target = handle.request.pose.pose
        gx, gy, gyaw = target.position.x, target.position.y, yaw_of(target.orientation)
        start = time.monotonic()
        result = NavigateToPose.Result()
        while True:
            if handle.is_cancel_requested:
                handle.canceled()
                say(event="canceled", x=self.x, y=self.y)
                return result
            if not handle.is_active:
                return result
            left = math.hypot(gx - self.x, gy - self.y)
            if left <= ARRIVED:
                self.x, self.y, self.yaw = gx, gy, gyaw
                handle.succeed()
                say(event="succeeded", x=self.x, y=self.y, yaw=self.yaw)
                return result
            step = min(SPEED * TICK, left)
            self.yaw = math.atan2(gy - self.y, gx - self.x)
            self.x += step * math.cos(self.yaw)
            self.y += step * math.sin(self.yaw)
            left = math.hypot(gx - self.x, gy - self.y)
            feedback = NavigateToPose.Feedback()
            feedback.current_pose = self.current_pose()
            elapsed = time.monotonic() - start
            feedback.navigation_time.sec = int(elapsed)
            feedback.navigation_time.nanosec = int((elapsed % 1) * 1e9)
            feedback.estimated_time_remaining.sec = int(left / SPEED)
            feedback.distance_remaining = left
            handle.publish_feedback(feedback)
            say(event="feedback", distance_remaining=round(left, 3))
            time.sleep(TICK)

    def current_pose(self):
        stamped = self.stamped()
        out = PoseStamped()
        out.header = stamped.header
        out.pose = stamped.pose.pose
        return out


def main():
    rclpy.init(args=sys.argv)
    node = Navigator()
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


if __name__ == "__main__":
    main()
