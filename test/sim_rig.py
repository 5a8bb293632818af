"""
Test helper: one real simulated servo (sim/servo.SimServo) on a clock of its own, no packets.

The physics tests drive the servo the product ships: every write goes through SimServo.write with
its table rules (EEPROM locked while torque is on, ranges, limits, torque on refused with a
latched shutdown error) and its side effects (mode changes, torque on/off, goals), and time
passes through SimServo.advance (its control period, its latching of hardware errors).
"""

import math

from dxl_servo_driver.protocol import ErrorCode
from dxl_servo_driver.sim.dynamics import ServoDynamics
from dxl_servo_driver.sim.memory import Memory
from dxl_servo_driver.sim.servo import SimServo

STEP_S = 0.001
SERVO_ID = 1


class Rig:
    """
    A SimServo of the manual's model (XM430), booted, in an operating mode, and its clock.

    mem and dyn are the servo's own control table and dynamics (for reading the physical state,
    setting the load or the supply, and the analytic jumps of dyn.advance); write() is a bus
    write, step() and run() let the servo's time pass.
    """

    def __init__(self, mode: int, volts: float = 12.0, start_pulse: float = 2048.0) -> None:
        self.now_s = 0.0
        dynamics = ServoDynamics(input_voltage_v=volts, start_position_pulse=start_pulse)
        # Booted at once: the tests write from the first moment.
        self.servo = SimServo(SERVO_ID, dynamics, self.now_s, boot_time_s=0.0)
        self.mem: Memory = self.servo.memory
        self.dyn: ServoDynamics = dynamics
        self.write(operating_mode=mode)

    def attempt(self, name: str, value: int) -> int:
        """Write one item as one bus write does; return the status error code (0: written)."""
        item = self.mem.item(name)
        try:
            payload = item.encode(int(value))
        except OverflowError:
            raise AssertionError(f'{name}={value} does not fit its {item.size} bytes') from None
        return self.servo.write(item.address, payload)

    def write(self, **values: int) -> None:
        """
        Write items as a bus does, one write each in the order given, with the servo's effects.

        AssertionError naming the item and the error code when the servo refuses one (the items
        before it stay written, as on a bus).
        """
        for name, value in values.items():
            code = self.attempt(name, value)
            if code:
                raise AssertionError(f'the servo refused {name}={value}: {ErrorCode(code).name}')

    def _tick(self, dt_s: float) -> None:
        """Move the clock dt_s on and let the servo catch up with it."""
        now_s = self.now_s + dt_s
        # At least dt_s on as the servo subtracts: a millisecond short of its control period by
        # a rounding error would skip a sample (the servo samples once per whole period).
        while now_s - self.now_s < dt_s:
            now_s = math.nextafter(now_s, math.inf)
        self.now_s = now_s
        self.servo.advance(now_s)

    def step(self) -> int:
        """Advance one millisecond; return the Hardware Error Status (the latched bits)."""
        self._tick(STEP_S)
        return self.mem.get('hardware_error_status')

    def run(self, seconds: float, dt_s: float = STEP_S) -> int:
        """Advance in dt_s steps; return the Hardware Error Status (the latched bits)."""
        for _ in range(int(round(seconds / dt_s))):
            self._tick(dt_s)
        return self.mem.get('hardware_error_status')

    def reg(self, name: str) -> int:
        """Return one register as the memory holds it now."""
        return self.mem.get(name)
