"""
Simulated Dynamixel XM430-class servos, faithful at the byte level.

Nothing in this package imports rclpy or dynamixel_sdk: the simulator is reached through a port
(in-process) or a pseudo-terminal, exactly as a real bus would be.
"""
