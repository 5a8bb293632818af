"""
The port a bus runs on: what a port is, the serial device, and Linux's tty speeds.

The face of the port layer. raw says what the bus needs of a port (RawPort: the serial device
and the simulator's ports both are one); serial_device opens a real adapter (every OS error a
PortError) and reads its latency timer; termios2 sets any baud rate a tty takes.
"""

from dxl_servo_driver.port.raw import port_paced, port_waited, RawPort
from dxl_servo_driver.port.serial_device import adapter_latency_timer_ms, open_port
from dxl_servo_driver.port.termios2 import set_tty_speed, tty_speed_bps

__all__ = ['adapter_latency_timer_ms', 'open_port', 'port_paced', 'port_waited', 'RawPort',
           'set_tty_speed', 'tty_speed_bps']
