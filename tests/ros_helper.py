"""Helper for the ROS tests, run under Debian's /usr/bin/python3 (rospy does not import elsewhere).

    ros_helper.py goal EFFECTOR X Y Z FRAME [TIMEOUT]   publish one goal, print the answers as JSON
    ros_helper.py motion EFFECTOR X Y Z                 publish one motion goal, print the trajectory as JSON
    ros_helper.py listen EFFECTOR                       print the next strategy published, whoever caused it
    ros_helper.py markers [TIMEOUT]            print a summary of the latched markers as JSON
    ros_helper.py alive NODE                   print whether a node answers
"""

from __future__ import annotations

import json
import sys
import threading

import rosnode
import rospy
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

TIMEOUT = 25.0  # [s] a busy machine (CI beside other work) answered a goal in more than 15 s once


def goal(effector: str, x: float, y: float, z: float, frame: str, timeout: float = TIMEOUT) -> None:
    got: dict = {}
    done = threading.Event()

    def keep(name):
        def cb(msg):
            got[name] = msg
            if len(got) == 3:
                done.set()
        return cb

    subs = [
        rospy.Subscriber(f"/reach/{effector}/strategy", String, keep("strategy")),
        rospy.Subscriber(f"/reach/{effector}/posture", JointState, keep("posture")),
        rospy.Subscriber(f"/reach/{effector}/reachable", Bool, keep("reachable")),
    ]
    pub = rospy.Publisher(f"/reach/{effector}/goal", PointStamped, queue_size=1, latch=True)
    # Publish only once the bridge hears us and we hear it, or its answers could be missed.
    deadline = rospy.Time.now() + rospy.Duration(TIMEOUT)
    while (pub.get_num_connections() == 0
           or any(s.get_num_connections() == 0 for s in subs)) and rospy.Time.now() < deadline:
        rospy.sleep(0.05)
    msg = PointStamped()
    msg.header.frame_id = frame
    msg.header.stamp = rospy.Time.now()
    msg.point.x, msg.point.y, msg.point.z = x, y, z
    pub.publish(msg)
    done.wait(timeout)
    out = {"received": sorted(got)}
    if "strategy" in got:
        out["strategy"] = got["strategy"].data
    if "reachable" in got:
        out["reachable"] = got["reachable"].data
    if "posture" in got:
        out["names"] = list(got["posture"].name)
        out["positions"] = list(got["posture"].position)
    print(json.dumps(out), flush=True)


def motion(effector: str, x: float, y: float, z: float) -> None:
    got: list = []
    done = threading.Event()
    sub = rospy.Subscriber(f"/reach/{effector}/motion", JointTrajectory, lambda msg: (got.append(msg), done.set()))
    pub = rospy.Publisher(f"/reach/{effector}/motion_goal", PointStamped, queue_size=1, latch=True)
    deadline = rospy.Time.now() + rospy.Duration(TIMEOUT)
    while (pub.get_num_connections() == 0 or sub.get_num_connections() == 0) and rospy.Time.now() < deadline:
        rospy.sleep(0.05)
    msg = PointStamped()
    msg.header.frame_id = "world"
    msg.point.x, msg.point.y, msg.point.z = x, y, z
    pub.publish(msg)
    done.wait(3 * TIMEOUT)
    if not got:
        print(json.dumps({"received": False}), flush=True)
        return
    t = got[0]
    print(json.dumps({"received": True, "frame": t.header.frame_id, "names": list(t.joint_names),
                      "times": [p.time_from_start.to_sec() for p in t.points],
                      "positions": [list(p.positions) for p in t.points]}), flush=True)


def listen(effector: str) -> None:
    """Print the first strategy published for effector, whoever caused it."""
    print(json.dumps({"ready": True}), flush=True)
    msg = rospy.wait_for_message(f"/reach/{effector}/strategy", String, timeout=TIMEOUT)
    print(json.dumps({"strategy": msg.data}), flush=True)


def markers(timeout: float = TIMEOUT) -> None:
    msg = rospy.wait_for_message("/reach/markers", MarkerArray, timeout=timeout)
    print(json.dumps({"markers": [{"ns": m.ns, "type": m.type, "points": len(m.points), "frame": m.header.frame_id,
                                    "colour": [m.color.r, m.color.g, m.color.b]} for m in msg.markers]}), flush=True)


if __name__ == "__main__":
    rospy.init_node("reach_test_helper", anonymous=True, disable_signals=True)
    mode = sys.argv[1]
    if mode == "motion":
        motion(sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5]))
    elif mode == "goal":
        goal(sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5]), sys.argv[6],
             *map(float, sys.argv[7:8]))
    elif mode == "listen":
        listen(sys.argv[2])
    elif mode == "markers":
        markers(*map(float, sys.argv[2:3]))
    elif mode == "alive":
        print(json.dumps({"alive": bool(rosnode.rosnode_ping(sys.argv[2], max_count=1))}), flush=True)
