"""The ROS 2 side of the driver: the node and what it is made of."""
