"""ROS 2 driver for Dynamixel X-series servos (Protocol 2.0) and its byte-level simulator."""
