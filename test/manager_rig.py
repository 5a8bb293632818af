"""A manager on the in-process simulated bus (no ROS), and the cycle steps the node runs."""

import time
from typing import Any, Callable, Dict, List, Optional, Tuple

from conditions import wait_until
from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.driver.transports import SimTransport
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.protocol import Instruction, Packet, StreamParser
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos

XM430_UNITS = units_for(model_for(1030))
SEED_BLOCK = state_block.state_block(model_for(1030), 'present_current')
# The block's fields by register name (effort is present_current on the XM430 manual's model).
STATE_NAMES = tuple(SEED_BLOCK.register(name) for name in SEED_BLOCK.names)

BAUD = 1_000_000


class TapPort:
    """The simulator's port, with a record of every packet the driver sent."""

    def __init__(self, port: SimPortHandler) -> None:
        self.port = port
        self.packets: List[Packet] = []
        self._parser = StreamParser()

    @property
    def baudrate(self) -> int:
        return self.port.baudrate

    def write(self, data: bytes) -> int:
        self.packets += [event.packet for event in self._parser.feed(bytes(data), 0.0)]
        return self.port.write(data)

    def read(self, size: int, timeout_s: float) -> bytes:
        return self.port.read(size, timeout_s)

    @property
    def in_waiting(self) -> int:
        return self.port.in_waiting

    def reset_input_buffer(self) -> None:
        self.port.reset_input_buffer()

    def close(self) -> None:
        self.port.close()

    def writes(self, servo_id: int) -> List[Tuple[int, bytes]]:
        """Return (address, data) of every WRITE sent to servo_id."""
        return [(p.params[0] | (p.params[1] << 8), p.params[2:]) for p in self.packets
                if p.instruction == Instruction.WRITE and p.servo_id == servo_id]

    def written_addresses(self, servo_id: int) -> List[int]:
        return [address for address, _ in self.writes(servo_id)]


class Rig:
    """A SimBus, its tapped port, and managers built on them."""

    def __init__(self, ids: Tuple[int, ...] = (1, 2, 3)) -> None:
        self.sim = SimBus(ids, boot_time_s=0.02)
        configure_servos(self.sim, BAUD, None)
        self.tap = TapPort(SimPortHandler(self.sim, 'sim', BAUD))
        self.logs: List[str] = []

    def open_port(self, _config: DriverConfig) -> SimTransport:
        def reopen() -> TapPort:
            # Like opening the device again: a new port on the same servos, same tap.
            self.tap.port = SimPortHandler(self.sim, 'sim', BAUD)
            return self.tap
        return SimTransport(self.sim, reopen)

    def manager(self, config: DriverConfig, **kwargs: Any) -> Manager:
        return Manager(config, info=self.logs.append, warn=self.logs.append,
                       error=self.logs.append, port_factory=self.open_port, **kwargs)

    def reg(self, servo_id: int, name: str) -> int:
        return self.sim.read_register(servo_id, name)

    def wait_booted(self, servo_id: int) -> None:
        wait_until(lambda: self.sim.servo(servo_id).responsive(time.monotonic()), 2.0,
                   f'servo {servo_id} booted')


def params(**extra: Any) -> Dict[str, Any]:
    base: Dict[str, Any] = {
        'port': 'sim', 'baud_rate': BAUD, 'latency_timer': 1.0,
        'joints': ['arm', 'wheel', 'grip'],
        'arm.id': 1, 'arm.operating_mode': 'position',
        'arm.registers.profile_velocity': 200, 'arm.registers.position_p_gain': 900,
        'arm.registers.return_delay_time': 0,
        'wheel.id': 2, 'wheel.operating_mode': 'velocity',
        'wheel.registers.return_delay_time': 0, 'wheel.registers.velocity_limit': 300,
        'grip.id': 3, 'grip.operating_mode': 'current',
        'grip.registers.return_delay_time': 0, 'grip.registers.current_limit': 500,
    }
    base.update(extra)
    return base


def cycle_read(manager: Manager, retry_until: Optional[float] = None,
               full: Optional[bool] = None) -> bool:
    """Run one state read of the cycle as the node does; False when nothing was read."""
    return manager.cycle_begin(full) and manager.cycle_end(retry_until)


def read_states(manager: Manager, full: Optional[bool] = None,
                retry_until: Optional[float] = None) -> None:
    """Read every servo's state once (cycle_read, whatever it found)."""
    cycle_read(manager, retry_until, full)


def motion_only(manager: Manager) -> None:
    """Read the whole block once, then only motion and tick (the health part not due again)."""
    manager.health_period_s = 3600.0
    read_states(manager, full=True)


def run_cycles(manager: Manager, done: Callable[[], bool], timeout_s: float = 5.0,
               step_s: float = 0.0) -> List[Dict[str, bool]]:
    """
    Run bus cycles (read, write, recovery steps) until done(); return who was fresh each cycle.

    With step_s 0 a cycle leaves recovery no time: one step per cycle, the tightest budget.
    """
    fresh = []
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, 'the cycles did not get there in time'
        cycle_read(manager, retry_until=time.monotonic() + 0.01)
        manager.cycle_write(tasks_until=time.monotonic() + step_s)
        fresh.append({servo.name: servo.fresh for servo in manager.order})
        time.sleep(0.001)
    return fresh


def no_tasks(manager: Manager) -> Callable[[], bool]:
    return lambda: not manager.tasks.tasks()
