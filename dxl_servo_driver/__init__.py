"""ROS 2 driver for Dynamixel servos (every family, Protocol 1.0 and 2.0) and its simulator."""
