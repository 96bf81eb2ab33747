"""``python3 -m ros_bridge``: run the bridge node (ROS arguments such as ``_server:=...`` pass through)."""

from ros_bridge.node import main

main()
