"""
The node on an infinitely fast bus: `port: sim` with the cycle's reads answered from records.

`python bench/ceiling_node.py --ros-args --params-file FILE` runs the node as `ros2 run` does,
except that its port is a ReplayPort (sim/replay.py) in front of the in-process simulator: the
first of each cycle read goes to the simulator, every later one is answered at once from its
record (ticks moved on), and sync writes are dropped once replaying. What is left of a cycle is
the node's own work: its rate is the node's ceiling, its CPU per cycle the node's alone.
"""

import pathlib
import sys

if __name__ == '__main__':   # the node of this source tree (cycle_cost.py imports this module)
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from dxl_servo_driver.config import DriverConfig  # noqa: E402 - after the path set-up above
from dxl_servo_driver.driver.state_block import BLOCK_SHAPE  # noqa: E402
from dxl_servo_driver.driver.transports import (  # noqa: E402
    open_transport, SimTransport, Transport)
from dxl_servo_driver.ros.main import main  # noqa: E402
from dxl_servo_driver.sim.port import SimPortHandler  # noqa: E402
from dxl_servo_driver.sim.replay import ReplayPort  # noqa: E402

# Where each servo's Realtime Tick lies in its part of the cycle's read: the last of the tagged
# part, which leads every read of the X layout (motion, tick, then health).
TICK_OFFSET = BLOCK_SHAPE.tagged_size - 2


def replay_transport(config: DriverConfig) -> Transport:
    """Return the simulated servos of `port: sim` behind a ReplayPort."""
    transport = open_transport(config)
    if not isinstance(transport, SimTransport):
        raise SystemExit('ceiling_node runs on port: sim only')
    simulator = transport.simulator
    return SimTransport(simulator, lambda: ReplayPort(
        SimPortHandler(simulator, 'sim', config.baud_rate), TICK_OFFSET))


if __name__ == '__main__':
    sys.exit(main(sys.argv, replay_transport))
