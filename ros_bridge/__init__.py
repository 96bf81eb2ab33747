"""ros_bridge: the reach selector on ROS 1 topics.

A thin ROS node that is a client of ``reach serve``; it loads no trees. It
runs under Debian's system Python (``/usr/bin/python3``) with Debian's ROS
packages: ``python3 -m ros_bridge`` with this repository on PYTHONPATH.
See :mod:`ros_bridge.node` for topics and parameters.
"""

__all__ = ["node"]
