"""Test helper: one simulated servo's control-table memory and its dynamics, no packets."""

from dxl_servo_driver.sim.dynamics import ServoDynamics
from dxl_servo_driver.sim.memory import Memory

STEP_S = 0.001


class Rig:
    """A real control-table memory plus the dynamics, with the servo's write side effects."""

    def __init__(self, mode: int, volts: float = 12.0, start_pulse: float = 2048.0) -> None:
        self.mem = Memory()
        self.dyn = ServoDynamics(input_voltage_v=volts, start_position_pulse=start_pulse)
        self.mem.set('operating_mode', mode)
        self.dyn.reinit_present_position(self.mem)
        self.mem.set('goal_position', self.mem.get('present_position'))
        self.dyn.advance(0.0, self.mem)

    def write(self, **values: int) -> None:
        """Write registers the way the servo does, then call the hooks it calls."""
        old_torque = self.mem.get('torque_enable')
        for name, value in values.items():
            self.mem.set(name, value)
        torque = self.mem.get('torque_enable')
        if 'torque_enable' in values and torque != old_torque:
            if torque:
                self.dyn.reinit_present_position(self.mem)
            self.dyn.on_torque(bool(torque), self.mem)
        if 'goal_position' in values:
            self.dyn.on_goal_position(self.mem)
        if 'goal_velocity' in values:
            self.dyn.on_goal_velocity(self.mem)

    def step(self) -> int:
        """Advance one millisecond; return the reported error bits."""
        return self.dyn.advance(STEP_S, self.mem)

    def run(self, seconds: float, dt_s: float = STEP_S) -> int:
        """Advance in dt_s calls; return the OR of the reported error bits."""
        errors = 0
        for _ in range(int(round(seconds / dt_s))):
            errors |= self.dyn.advance(dt_s, self.mem)
        return errors

    def reg(self, name: str) -> int:
        """Return one register as the memory holds it now."""
        return self.mem.get(name)
