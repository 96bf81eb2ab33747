"""The ROS-free core of ros_bridge (runs without ROS)."""

from __future__ import annotations


def test_relay_publishes_each_choice_once_and_repeated_goals_again():
    # a reply's echo on the stream is skipped once; a repeated goal is not.
    from ros_bridge.node import Relay

    relay = Relay()
    answer = {"effector": "right_hand", "goal": [0.4, -0.3, 1.2], "strategy": "right_arm", "reachable": True,
              "posture": {"b": 2.0, "a": 1.0}}
    assert relay.values(answer) == ("right_arm", ["a", "b"], [1.0, 2.0], True)
    relay.replied(answer)
    relay.replied(answer)  # the same goal asked twice: two replies, two echoes
    assert relay.is_echo(answer) and relay.is_echo(answer) and not relay.is_echo(answer)
    other = {**answer, "goal": [0.5, -0.3, 1.2]}
    assert not relay.is_echo(other)  # another client's choice: relayed
