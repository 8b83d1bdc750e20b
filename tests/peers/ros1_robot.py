"""A ROS 1 robot for ferrosa's ROS 1 tests, written with Debian's rospy (run it with
/usr/bin/python3): node /turtlesim with a turtle's pose (turtlesim/Pose) following
/turtle1/cmd_vel, /turtle1/teleport_absolute and /reset, the parameters
~background_r/g/b, a warning on /rosout every second, and an inspection sensor of a type
no one ships (field_msgs/Reading, published; field_msgs/Command, subscribed; each command
received is logged and kept in ~last_command).

Types rospy has no generated code for are made at start from their text (genpy.dynamic),
services with the md5sum genmsg computes, as generated code would have them.
"""
import math
import sys

import genmsg
import genmsg.msg_loader
import genpy.dynamic
import rospy
from geometry_msgs.msg import Twist
from std_srvs.srv import Empty, EmptyResponse

POSE = "float32 x\nfloat32 y\nfloat32 theta\n\nfloat32 linear_velocity\nfloat32 angular_velocity\n"
READING = "Header header\nstring sensor\nfloat64 value\nstring unit\n"
COMMAND = "string action\nfloat32 level\n"
TELEPORT = ("float32 x\nfloat32 y\nfloat32 theta\n", "")


def message(name, text):
    if "Header header" in text:
        text += "=" * 80 + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    return genpy.dynamic.generate_dynamic(name, text)[name]


def service(name, request, response):
    ctx = genmsg.MsgContext.create_default()
    spec = genmsg.msg_loader.load_srv_from_string(ctx, request + "---\n" + response, name)
    md5 = genmsg.compute_md5(ctx, spec)
    req = message(name + "Request", request)
    res = message(name + "Response", response)
    for cls in (req, res):
        cls._md5sum = md5
    return type(name.split("/")[1], (object,), {
        "_type": name, "_md5sum": md5, "_request_class": req, "_response_class": res})


def main():
    rospy.init_node("turtlesim", disable_signals=True)
    Pose = message("turtlesim/Pose", POSE)
    Reading = message("field_msgs/Reading", READING)
    Command = message("field_msgs/Command", COMMAND)
    Teleport = service("turtlesim/TeleportAbsolute", *TELEPORT)
    for c, v in zip("rgb", (69, 86, 255)):
        rospy.set_param("~background_" + c, v)
    state = {"x": 5.544, "y": 5.544, "theta": 0.0, "v": 0.0, "w": 0.0, "until": 0.0}

    def on_twist(t):
        state.update(v=t.linear.x, w=t.angular.z, until=rospy.get_time() + 1.0)

    def on_command(c):
        text = "action=%s level=%.1f" % (c.action, c.level)
        rospy.set_param("~last_command", text)
        rospy.loginfo("inspection command received: " + text)

    def teleport(req):
        state.update(x=req.x, y=req.y, theta=req.theta)
        return Teleport._response_class()

    def reset(_):
        state.update(x=5.544, y=5.544, theta=0.0, v=0.0, w=0.0)
        return EmptyResponse()

    rospy.Subscriber("/turtle1/cmd_vel", Twist, on_twist)
    rospy.Subscriber("/inspection/command", Command, on_command)
    rospy.Service("/turtle1/teleport_absolute", Teleport, teleport)
    rospy.Service("/reset", Empty, reset)
    pose = rospy.Publisher("/turtle1/pose", Pose, queue_size=10)
    reading = rospy.Publisher("/inspection/reading", Reading, queue_size=10)
    rospy.loginfo("Starting turtlesim with node name /turtlesim")
    rate, tick = rospy.Rate(20), 0
    while not rospy.is_shutdown():
        now = rospy.get_time()
        v, w = (state["v"], state["w"]) if now < state["until"] else (0.0, 0.0)
        state["theta"] = math.atan2(math.sin(state["theta"] + w / 20), math.cos(state["theta"] + w / 20))
        state["x"] = min(max(state["x"] + v / 20 * math.cos(state["theta"]), 0.0), 11.09)
        state["y"] = min(max(state["y"] + v / 20 * math.sin(state["theta"]), 0.0), 11.09)
        pose.publish(Pose(x=state["x"], y=state["y"], theta=state["theta"],
                          linear_velocity=v, angular_velocity=w))
        tick += 1
        if tick % 10 == 0:
            r = Reading(sensor="thermal_cam", value=41.5, unit="celsius")
            r.header.stamp = rospy.Time.now()
            reading.publish(r)
        if tick % 20 == 0:
            rospy.logwarn("battery low: 18%")
        rate.sleep()


if __name__ == "__main__":
    sys.exit(main())
