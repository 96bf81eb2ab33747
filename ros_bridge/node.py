"""The reach bridge node: goals in on ROS topics, the selector's answers out.

Design: three layers, of which only the last knows ROS, so that a ROS 2
(rclpy) version swaps that layer alone.

1. ``reach.serving.client.Client`` talks to the server (Lazy Pirate REQ, timeouts,
   reconnection) and a ZeroMQ SUB socket receives the server's stream of
   choices. Neither imports ROS.
2. ``Relay`` turns answers into plain values (strategy name, joint names and
   positions, reachable) and recognises the stream's copy of an answer the
   bridge already published from its reply, so each choice is published once.
3. ``Bridge`` is the ROS 1 node: parameters, subscribers, publishers, timers.

Topics, for each effector E (the server's effectors, or ``~effectors``):

* in: ``<prefix>/E/goal`` (geometry_msgs/PointStamped). The header's frame
  must be ``~frame``; another frame is logged as an error and ignored.
* out: ``<prefix>/E/strategy`` (std_msgs/String; empty when none reaches),
  ``<prefix>/E/posture`` (sensor_msgs/JointState: the model's joint names,
  radians), ``<prefix>/E/reachable`` (std_msgs/Bool).
* in: ``<prefix>/E/motion_goal`` (geometry_msgs/PointStamped, frame ``~frame``):
  plan the reach motion to the goal from the reference posture (the
  server's ``motion`` operation, 30 Hz);
* out: ``<prefix>/E/motion`` (trajectory_msgs/JointTrajectory): its frames,
  the model's joint names, radians, ``time_from_start`` [s]; the floating
  root's pose is not a joint and is not in the message;
* out, latched: ``<prefix>/markers`` (visualization_msgs/MarkerArray): each
  strategy's reachable cells as a cube list, one colour per strategy.

Choices other clients cause (the server's PUB stream) are relayed to the
same topics; the stream carries only a motion's summary, not its frames, so
motions other clients ask for are not relayed. If the server is down, goals get an error in the log and the
node keeps running; markers are retried until they are published.

Parameters (private, with defaults): ``~server`` (tcp://127.0.0.1:5555),
``~pub`` (tcp://127.0.0.1:5556; empty to not relay), ``~frame`` (world),
``~prefix`` (/reach), ``~effectors`` (all the server has), ``~timeout_ms``
(2500), ``~motion_timeout_ms`` (20000: a whole-body motion takes seconds to plan), ``~retries`` (3),
``~marker_level`` (4: 2**4 cells per axis),
``~relay_hz`` (100: how often the stream is polled), ``~marker_retry_s`` (2).
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter, deque
from typing import Any

import zmq

from reach.serving import protocol as P
from reach.serving.client import REQUEST_RETRIES, REQUEST_TIMEOUT_MS, Client, ServerError, ServerUnavailable

MOTION_TIMEOUT_MS = 20_000
COLOURS = [(0.84, 0.15, 0.16), (0.17, 0.63, 0.17), (0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.58, 0.4, 0.74),
           (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.09, 0.75, 0.81)]


class Relay:
    """ROS-free core: answers to plain values, and recognising the stream's echo of our own replies.

    The server publishes every choice, including those the bridge asked for
    and has already published from the reply; each of those is expected once
    on the stream and skipped there. Everything else on the stream is relayed.
    """

    def __init__(self, memory: int = 1024) -> None:
        self.expected: Counter[tuple[str, tuple[float, ...], str | None]] = Counter()
        self.order: deque[tuple[str, tuple[float, ...], str | None]] = deque()
        self.memory = memory

    @staticmethod
    def key(answer: dict[str, Any]) -> tuple[str, tuple[float, ...], str | None]:
        return str(answer.get("effector")), tuple(round(float(v), 9)
                                                  for v in answer.get("goal", [])), answer.get("strategy")

    @staticmethod
    def values(answer: dict[str, Any]) -> tuple[str, list[str], list[float], bool]:
        posture = answer.get("posture") or {}
        names = sorted(posture)
        return answer.get("strategy") or "", names, [float(posture[n]) for n in names], bool(answer.get("reachable"))

    def replied(self, answer: dict[str, Any]) -> None:
        """Note that this answer came as a reply and was published: its echo on the stream is to be skipped."""
        k = self.key(answer)
        self.expected[k] += 1
        self.order.append(k)
        if len(self.order) > self.memory:  # echoes that never came (a lossy or absent stream) are forgotten
            old = self.order.popleft()
            self.expected[old] -= 1
            if self.expected[old] <= 0:
                del self.expected[old]

    def is_echo(self, answer: dict[str, Any]) -> bool:
        """True (once) for the stream's copy of an answer already published from a reply."""
        k = self.key(answer)
        if self.expected.get(k, 0) <= 0:
            return False
        self.expected[k] -= 1
        if self.expected[k] == 0:
            del self.expected[k]
        return True


class Bridge:
    """The ROS 1 node (rospy)."""

    def __init__(self) -> None:
        import rospy
        from geometry_msgs.msg import PointStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, String
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
        from visualization_msgs.msg import MarkerArray

        self.rospy = rospy
        self.msgs = {"JointState": JointState, "String": String, "Bool": Bool, "JointTrajectory": JointTrajectory,
                     "JointTrajectoryPoint": JointTrajectoryPoint}
        p = rospy.get_param
        self.server = p("~server", P.DEFAULT_BIND)
        self.pub_address = p("~pub", P.DEFAULT_PUB)
        self.frame = p("~frame", P.WORLD_FRAME)
        self.prefix = p("~prefix", "/reach").rstrip("/")
        self.marker_level = int(p("~marker_level", 4))
        self.client = Client(self.server, timeout=int(p("~timeout_ms", REQUEST_TIMEOUT_MS)),
                             retries=int(p("~retries", REQUEST_RETRIES)))
        # Motions on their own connection: one takes seconds, and a REQ socket is one thread's.
        self.motions = Client(self.server, timeout=int(p("~motion_timeout_ms", MOTION_TIMEOUT_MS)), retries=1)
        self.motion_lock = threading.Lock()
        self.relay = Relay()
        effectors = p("~effectors", [])
        while not effectors and not rospy.is_shutdown():
            try:
                effectors = self.client.strategies()["effectors"]
            except (ServerUnavailable, ServerError) as exc:
                rospy.logerr("reach bridge: cannot list effectors from %s (%s); retrying", self.server, exc)
                time.sleep(1.0)
        self.pubs: dict[str, dict[str, Any]] = {}
        for e in effectors:
            self.pubs[e] = {
                "strategy": rospy.Publisher(f"{self.prefix}/{e}/strategy", String, queue_size=10),
                "posture": rospy.Publisher(f"{self.prefix}/{e}/posture", JointState, queue_size=10),
                "reachable": rospy.Publisher(f"{self.prefix}/{e}/reachable", Bool, queue_size=10),
                "motion": rospy.Publisher(f"{self.prefix}/{e}/motion", JointTrajectory, queue_size=10),
            }
            rospy.Subscriber(f"{self.prefix}/{e}/goal", PointStamped, self.on_goal, callback_args=e, queue_size=10)
            rospy.Subscriber(f"{self.prefix}/{e}/motion_goal", PointStamped, self.on_motion_goal, callback_args=e,
                             queue_size=10)
        self.markers = rospy.Publisher(f"{self.prefix}/markers", MarkerArray, queue_size=1, latch=True)
        self.markers_done = False
        rospy.Timer(rospy.Duration(float(p("~marker_retry_s", 2.0))), self.publish_markers)
        self.sub = None
        if self.pub_address:
            self.sub = zmq.Context.instance().socket(zmq.SUB)
            self.sub.setsockopt(zmq.LINGER, 0)
            self.sub.setsockopt(zmq.SUBSCRIBE, b"")
            self.sub.connect(self.pub_address)
            rospy.Timer(rospy.Duration(1.0 / float(p("~relay_hz", 100.0))), self.relay_stream)
        rospy.loginfo("reach bridge: server %s, effectors %s, frame %s", self.server, ", ".join(effectors), self.frame)

    def _goal(self, msg: Any, effector: str) -> list[float] | None:
        """The goal of a PointStamped [m], or None (logged) when it is in another frame."""
        frame = msg.header.frame_id
        if frame != self.frame:
            self.rospy.logerr("reach bridge: goal for %s in frame %r ignored; goals must be in frame %r", effector,
                              frame, self.frame)
            return None
        return [msg.point.x, msg.point.y, msg.point.z]

    def on_motion_goal(self, msg: Any, effector: str) -> None:
        goal = self._goal(msg, effector)
        if goal is None:
            return
        try:
            with self.motion_lock:
                motion = self.motions.motion(effector=effector, goal=goal)
        except (ServerError, ServerUnavailable) as exc:
            self.rospy.logerr("reach bridge: no motion of %s to %s: %s", effector, goal, exc)
            return
        self.pubs[effector]["motion"].publish(self.trajectory(motion))

    def trajectory(self, motion: dict[str, Any]) -> Any:
        """A motion's frames as a JointTrajectory: the joints in name order, positions [rad or m] at each frame's
        time."""
        names = sorted(motion["frames"][0]["posture"])
        out = self.msgs["JointTrajectory"]()
        out.header.stamp = self.rospy.Time.now()
        out.header.frame_id = self.frame
        out.joint_names = names
        for frame in motion["frames"]:
            point = self.msgs["JointTrajectoryPoint"]()
            point.positions = [float(frame["posture"][n]) for n in names]
            point.time_from_start = self.rospy.Duration.from_sec(float(frame["t"]))
            out.points.append(point)
        return out

    def on_goal(self, msg: Any, effector: str) -> None:
        rospy = self.rospy
        goal = self._goal(msg, effector)
        if goal is None:
            return
        try:
            answer = self.client.query(effector, goal)
        except ServerError as exc:
            rospy.logerr("reach bridge: server refused goal %s for %s: %s", goal, effector, exc)
            return
        except ServerUnavailable as exc:
            rospy.logerr("reach bridge: %s", exc)
            return
        self.publish(effector, answer)
        self.relay.replied(answer)

    def publish(self, effector: str, answer: dict[str, Any]) -> None:
        if effector not in self.pubs:
            return
        strategy, names, positions, reachable = self.relay.values(answer)
        state = self.msgs["JointState"]()
        state.header.stamp = self.rospy.Time.now()
        state.header.frame_id = self.frame
        state.name, state.position = names, positions
        self.pubs[effector]["strategy"].publish(self.msgs["String"](data=strategy))
        self.pubs[effector]["posture"].publish(state)
        self.pubs[effector]["reachable"].publish(self.msgs["Bool"](data=reachable))

    def relay_stream(self, _event: Any = None) -> None:
        """Publish what the server's stream carried since the last poll."""
        while self.sub is not None:
            try:
                topic, body = self.sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            try:
                answer = json.loads(body)
                if "frame_count" in answer:
                    continue  # a motion's summary: its frames went to the client that asked
                if not self.relay.is_echo(answer):
                    self.publish(topic.decode(), answer)
            except (ValueError, UnicodeDecodeError) as exc:
                self.rospy.logwarn("reach bridge: unreadable message on the stream: %s", exc)

    def publish_markers(self, _event: Any = None) -> None:
        if self.markers_done:
            return
        from geometry_msgs.msg import Point
        from visualization_msgs.msg import Marker, MarkerArray

        try:
            cells = self.client.cells(level=self.marker_level)
        except (ServerUnavailable, ServerError) as exc:
            self.rospy.logwarn("reach bridge: markers not yet available: %s", exc)
            return
        array = MarkerArray()
        for k, (name, c) in enumerate(sorted(cells.items(), key=lambda kv: (kv[1].get("priority") or 0, kv[0]))):
            m = Marker()
            m.header.frame_id = self.frame
            m.header.stamp = self.rospy.Time.now()
            m.ns, m.id, m.type, m.action = name, k, Marker.CUBE_LIST, Marker.ADD
            m.pose.orientation.w = 1.0
            m.scale.x, m.scale.y, m.scale.z = c["size"]
            r, g, b = COLOURS[k % len(COLOURS)]
            m.color.r, m.color.g, m.color.b, m.color.a = r, g, b, 0.4
            m.points = [Point(x=x, y=y, z=z) for x, y, z in c["centres"]]
            array.markers.append(m)
        self.markers.publish(array)
        self.markers_done = True
        self.rospy.loginfo("reach bridge: published markers of %d strategies", len(array.markers))


def main() -> None:
    import rospy

    rospy.init_node("reach_bridge")
    Bridge()
    rospy.spin()
