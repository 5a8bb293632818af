"""
`dxl`: the servo tool. Set up, inspect, back up, calibrate, look at and trace Dynamixel servos.

One executable with subcommands (`dxl <command> --help` says each, with an example). Plain
command line, no ROS graph: it talks to the servos through `dxl_servo_driver.bus.Bus` on any
port the driver takes (a serial device, `virtual_bus`'s pty). The top layer, beside ros/ (neither
imports the other): it may use every layer below it, and nothing imports it.

Each subcommand is a module of this package with `register(subparsers)`, which adds its parser
and sets `run` (a function of the parsed arguments returning the exit status); `main.COMMANDS`
lists them in the order `dxl --help` shows.
"""
