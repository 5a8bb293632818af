"""
The least a Python ROS 2 process can do in the `top` case: the floor the node is set against.

`python bench/floor_loop.py DEVICE BAUD N SECONDS NAMESPACE` runs, at 100 Hz on the same
simulated bus, what any driver written with rclpy must do each cycle and nothing else: wake for
the cycle, write a sync read of N servos (the node's 12 bytes each), sleep until the replies are
due (timer slack 1 ns, as the node's cycle thread), read them, publish one joint_states of ready
bytes. No check, no decode, no dating, no goals, no executor work. It prints one JSON line: the
cycles, the wall and CPU seconds of the measured stretch (this process's own accounting, all its
threads, as `top` counts them) and the replies it got.
"""

import json
import os
import pathlib
import select
import sys
import time
import tty

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from dxl_servo_driver import protocol  # noqa: E402 - after the path set-up above
from dxl_servo_driver.driver.state_block import BLOCK_SHAPE  # noqa: E402
from dxl_servo_driver.port import set_tty_speed  # noqa: E402
from dxl_servo_driver.timerslack import fine_timer_slack  # noqa: E402
import rclpy  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

PERIOD_S = 0.01
WARM_UP_S = 1.0
PRESENT_CURRENT = 126   # 12 bytes from here: as many as the node's usual read of each servo


def main() -> None:
    """Run the loop and print its figures."""
    device, baud, n, seconds, namespace = sys.argv[1:6]
    baud_bps, count = int(baud), int(n)
    rclpy.init()
    node = rclpy.create_node('bench_floor')
    publisher = node.create_publisher(JointState, f'{namespace}/joint_states', 10)
    names = [f'j{i}' for i in range(1, count + 1)]
    message = serialize_message(JointState(name=names, position=[0.0] * count,
                                           velocity=[0.0] * count, effort=[0.0] * count))
    fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    set_tty_speed(fd, baud_bps)
    length = BLOCK_SHAPE.tagged_size
    request = protocol.encode_instruction(
        protocol.BROADCAST_ID, protocol.Instruction.SYNC_READ,
        PRESENT_CURRENT.to_bytes(2, 'little') + length.to_bytes(2, 'little')
        + bytes(range(1, count + 1)))
    expected = count * (protocol.STATUS_OVERHEAD + length)
    wire_s = (len(request) + expected) * protocol.BITS_PER_BYTE / baud_bps
    fine_timer_slack()
    cycles = replies = 0
    begin_s = time.monotonic()
    count_from_s = begin_s + WARM_UP_S
    cpu0 = wall0 = 0.0
    next_s = begin_s
    while True:
        now = time.monotonic()
        if cycles == 0 and now >= count_from_s and not cpu0:
            cpu0, wall0 = time.process_time(), now
        if wall0 and now - wall0 >= float(seconds):
            break
        os.write(fd, request)
        time.sleep(wire_s)
        got = os.read(fd, expected)
        while len(got) < expected and select.select([fd], [], [], 0.005)[0]:
            got += os.read(fd, expected - len(got))   # the simulator answered late: wait on
        publisher.publish(message)
        if wall0:
            cycles += 1
            replies += len(got) == expected
        next_s += PERIOD_S
        delay = next_s - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)
    wall = time.monotonic() - wall0
    cpu = time.process_time() - cpu0
    os.close(fd)
    node.destroy_node()
    rclpy.try_shutdown()
    print(json.dumps({'cycles': cycles, 'wall_s': wall, 'cpu_s': cpu, 'whole_replies': replies}),
          flush=True)


if __name__ == '__main__':
    main()
