"""
Simulated Dynamixel servos of every supported model, faithful at the byte level.

Any model of the catalogue (dxl_servo_driver.models) can be simulated: its control table,
units and datasheet physics; the default is the XM430 manual's model 1030.

Nothing in this package imports rclpy or dynamixel_sdk: the simulator is reached through a port
(in-process) or a pseudo-terminal, exactly as a real bus would be.
"""
