"""
One simulated servo: its control table, time, power, latched errors and the side effects of writes.

It hears the protocol its Protocol Version register names: sim/protocol2.py answers Protocol 2.0
packets (handle() dispatches there), sim/protocol1.py Protocol 1.0; both act through this
servo's memory and write(), so the side effects are the same in either.

The physics lives in dynamics.ServoDynamics; this class owns the control table (its model's:
items, modes, bauds, and the Firmware Version it reports), time, power and the latched hardware
errors.  Choices where the manual is silent (all documented here; the instructions' own are in
sim/protocol2.py):
- Writing torque_enable=1 while a hardware error bit that is set in `shutdown` is latched is
  refused with Result Fail (nothing written); REBOOT or a power cycle clears the latch.
- REBOOT/FACTORY_RESET restart the servo once their status went out: unresponsive for
  boot_time_s, RAM defaults, latched errors cleared, present position re-initialised within one
  turn, goal_position := present_position (as after power-on).
- Power-on (powercycle, plug) is the same restart without touching EEPROM.
- Torque enable 0 -> 1 in a position mode holds the horn where it is (the dynamics) and sets
  goal_position := present_position, so the register shows the goal the servo holds. A driver
  should still write goal = present first: in the other modes the goals are kept as written.
- A hand may turn the horn only while torque is off (turn: with torque on the motor holds it);
  it turns an unpowered servo's horn too. End stops (set_stops) bound the horn whatever moves
  it (dynamics.py).
"""

import math
from typing import Protocol

from dxl_servo_driver.models import Model, modes
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.models.xm430 import TICK_PERIOD_MS
from dxl_servo_driver.protocol import (
    BROADCAST_ID, ErrorCode, MAX_ID, ParseEvent, RETURN_DELAY_UNIT_S)
from dxl_servo_driver.sim import protocol2
from dxl_servo_driver.sim.dynamics import CONTROL_PERIOD_S
from dxl_servo_driver.sim.memory import Memory, TableError
# Named here for the tests: the 2.0 dispatch table (one dict: a test may stand a handler in for
# one) and the BULK_WRITE parser.
from dxl_servo_driver.sim.protocol2 import HANDLERS as _HANDLERS  # noqa: F401
from dxl_servo_driver.sim.protocol2 import parse_bulk_write  # noqa: F401


class Dynamics(Protocol):
    """What the servo needs from dynamics.ServoDynamics."""

    def advance(self, dt_s: float, regs: Memory) -> int:
        """Run the physics for dt_s; return detected hardware error bits."""

    def on_goal_position(self, regs: Memory) -> None:
        """goal_position was written."""

    def on_goal_velocity(self, regs: Memory) -> None:
        """goal_velocity was written."""

    def on_torque(self, enabled: bool, regs: Memory) -> None:
        """torque_enable changed."""

    def reinit_present_position(self, regs: Memory) -> None:
        """Re-initialise present_position within one turn."""

    def reset_controllers(self) -> None:
        """Reset integrators and profile state."""

    def set_load(self, load_nm: float) -> None:
        """Set the resisting torque at the horn."""

    def set_input_voltage(self, volts: float) -> None:
        """Set the supply voltage."""

    def start_turn(self, rad: float, seconds: float, regs: Memory) -> None:
        """Turn the horn by hand to rad (servo radians) over seconds."""

    def hand_coast(self, dt_s: float) -> None:
        """Move an unpowered servo's horn as the hand turns it."""

    def set_stops(self, low_rad: float, high_rad: float, regs: Memory) -> None:
        """Put end stops at low_rad..high_rad (servo radians)."""

    def clear_stops(self) -> None:
        """Take the end stops away."""


class SimServo:
    """One servo on the simulated bus."""

    def __init__(self, servo_id: int, dynamics: Dynamics, now_s: float,
                 boot_time_s: float = 0.1, model: Model | None = None,
                 firmware_version: int | None = None) -> None:
        if not 0 <= servo_id <= MAX_ID:
            raise ValueError(f'servo id {servo_id} outside 0..{MAX_ID}')
        self.memory = Memory(model, firmware_version)
        self.model = self.memory.model
        # The one-byte registers read on every packet, by address (the model's, looked up once).
        table = self.memory.table
        self._id_address = table.id_address
        self._baud_address = table.baud_address
        self._return_delay_address = table.return_delay_address
        self._error_mask = table.error_mask
        protocol_item = table.by_name.get('protocol_version')
        self._protocol_address = None if protocol_item is None else protocol_item.address
        # Registers of one model moved by another's physics would be a servo that lies.
        dynamics_model = getattr(dynamics, 'model', self.model)
        if dynamics_model is not self.model:
            raise ValueError(f'the dynamics are of the {dynamics_model.label}, the table of the '
                             f'{self.model.label}')
        self._bauds = self.model.bauds
        # A Baud Rate value without a baud (not written by a bus: the table refuses it).
        self._fallback_bps = self._bauds[self.model.item('baud_rate').initial]
        self.memory.set('id', servo_id)
        self.dynamics = dynamics
        self.boot_time_s = boot_time_s
        self.powered = True
        self._last_s = now_s
        self._power_on_s = now_s
        self._ready_s = now_s
        self._registered: tuple[int, bytes] | None = None
        self._restart(now_s, boot_delay=False)

    # ---- state ---------------------------------------------------------------------------------
    @property
    def servo_id(self) -> int:
        """Return the id the servo answers to now."""
        return self.memory.raw[self._id_address]

    @property
    def baud_bps(self) -> int:
        """Return the baud rate the servo listens at."""
        return self._bauds.get(self.memory.raw[self._baud_address], self._fallback_bps)

    @property
    def return_delay_s(self) -> float:
        """Return the Return Delay Time (the register times its unit, 2 us)."""
        return self.memory.raw[self._return_delay_address] * RETURN_DELAY_UNIT_S

    @property
    def protocol_version(self) -> int:
        """Return the protocol it speaks now: its Protocol Version, else its model's one."""
        address = self._protocol_address
        return int(self.model.protocol) if address is None else self.memory.raw[address]

    def responsive(self, now_s: float) -> bool:
        """Return whether the servo hears packets at now_s (powered and booted)."""
        return self.powered and now_s >= self._ready_s

    def hears(self, target: int, version: int, now_s: float) -> bool:
        """Return whether a packet of this protocol to target, heard at now_s, is this servo's."""
        return (self.responsive(now_s) and self.protocol_version == version
                and target in (self.servo_id, BROADCAST_ID))

    @property
    def physics_time_s(self) -> float:
        """Return the time the physics was last advanced to."""
        return self._last_s

    def advance(self, now_s: float, lag_s: float = 0.0) -> None:
        """Run the physics up to now_s (unless it is less than lag_s behind) and latch errors."""
        dt_s = now_s - self._last_s
        memory = self.memory
        if self.powered and dt_s > 0.0:
            # The Realtime Tick is the servo's clock, not physics: current even while the
            # physics may lag (a driver dates samples by it).
            tick_ms = int((now_s - self._power_on_s) * 1000.0)
            memory.set('realtime_tick', max(tick_ms, 0) % TICK_PERIOD_MS)
        if dt_s < lag_s:
            return
        if dt_s <= 0.0:
            return
        if not self.powered:
            self.dynamics.hand_coast(dt_s)   # a hand still turns an unpowered horn
            self._last_s = now_s
            return
        # The servo's controllers sample once per control period: packets closer together
        # than that see the registers of the last sample, which also keeps a busy bus cheap.
        if dt_s >= CONTROL_PERIOD_S:
            self._last_s = now_s
            self.latch_errors(self.dynamics.advance(dt_s, memory))

    def set_tick(self, now_s: float, tick_ms: int) -> None:
        """
        Make the Realtime Tick read tick_ms at now_s and count on from there.

        As if powered on that long ago, modulo the wrap: a servo that has run for hours, or a
        tick about to wrap.
        """
        if not 0 <= tick_ms < TICK_PERIOD_MS:
            raise ValueError(f'a Realtime Tick is 0..{TICK_PERIOD_MS - 1} ms, got {tick_ms}')
        self.advance(now_s)
        self._power_on_s = now_s - tick_ms / 1000.0
        self.memory.set('realtime_tick', tick_ms)

    def turn(self, now_s: float, rad: float, seconds: float) -> None:
        """
        Turn the horn by hand to rad (servo radians) over seconds from now_s (0: at once).

        ValueError while torque is on: the motor holds the horn.
        """
        if not seconds >= 0.0 or not math.isfinite(seconds) or not math.isfinite(rad):
            raise ValueError(f'a turn needs a finite angle and a time >= 0 s, got {rad} rad '
                             f'over {seconds} s')
        self.advance(now_s)
        if self.powered and self.memory.get('torque_enable'):
            raise ValueError('torque is on: the motor holds it; use load')
        self.dynamics.start_turn(rad, seconds, self.memory)
        self._publish_now()

    def set_stops(self, now_s: float, stops: tuple[float, float] | None) -> None:
        """Put mechanical end stops at (low, high) servo radians, or take them away (None)."""
        self.advance(now_s)
        if stops is None:
            self.dynamics.clear_stops()
            return
        low, high = stops
        if not (math.isfinite(low) and math.isfinite(high) and low <= high):
            raise ValueError(f'bad stops {low:g}..{high:g} rad: expected finite MIN <= MAX')
        self.dynamics.set_stops(low, high, self.memory)

    def _publish_now(self) -> None:
        """Show a change of the horn in the present registers at once (a zero-length step)."""
        if self.powered:
            self.latch_errors(self.dynamics.advance(0.0, self.memory))

    def latch_errors(self, bits: int) -> None:
        """Latch hardware error bits; drop torque for those set in `shutdown`."""
        bits &= self._error_mask  # the model's bits only (7, 6 and 1 are unused)
        if not bits:
            return
        memory = self.memory
        memory.set('hardware_error_status', memory.get('hardware_error_status') | bits)
        if bits & memory.get('shutdown') and memory.get('torque_enable'):
            memory.set('torque_enable', 0)
            self.dynamics.on_torque(False, memory)

    def power_off(self, now_s: float) -> None:
        """Cut the power: torque drops, the servo stops hearing the bus."""
        self.advance(now_s)
        if self.powered and self.memory.get('torque_enable'):
            self.memory.set('torque_enable', 0)
            self.dynamics.on_torque(False, self.memory)
        self.powered = False

    def power_on(self, now_s: float) -> None:
        """Power back on: EEPROM kept, RAM defaults, boot_time_s until it answers."""
        self.advance(now_s)
        self.powered = True
        self._restart(now_s, boot_delay=True)

    def _restart(self, now_s: float, boot_delay: bool) -> None:
        memory = self.memory
        if memory.get('torque_enable'):
            memory.set('torque_enable', 0)
            self.dynamics.on_torque(False, memory)
        memory.reset_ram()
        self._registered = None
        self._last_s = now_s
        self._power_on_s = now_s
        self._ready_s = now_s + (self.boot_time_s if boot_delay else 0.0)
        dynamics = self.dynamics
        dynamics.reset_controllers()
        dynamics.reinit_present_position(memory)
        memory.set('goal_position', memory.get('present_position'))
        # Fill the present_* registers at once (a zero-length step).
        self.latch_errors(dynamics.advance(0.0, memory))

    # ---- packets -------------------------------------------------------------------------------
    def handle(self, event: ParseEvent, now_s: float) -> bytes | None:
        """Act on one Protocol 2.0 packet heard at now_s; return the status packet, if any."""
        return protocol2.handle(self, event, now_s)

    def restart(self, now_s: float) -> None:
        """Restart as after REBOOT: unresponsive for boot_time_s, RAM defaults, errors cleared."""
        self._restart(now_s, boot_delay=True)

    def register(self, address: int, payload: bytes) -> None:
        """Keep a checked REG_WRITE until ACTION (a newer one replaces it)."""
        self._registered = (address, bytes(payload))
        self.memory.set('registered_instruction', 1)

    def take_registered(self) -> tuple[int, bytes] | None:
        """Return the REG_WRITE waiting for ACTION, and forget it (None: none waits)."""
        registered = self._registered
        if registered is not None:
            self._registered = None
            self.memory.set('registered_instruction', 0)
        return registered

    def clear_multi_turn(self) -> None:
        """Re-initialise the present position within one turn (CLEAR's multi-turn reset)."""
        self.dynamics.reinit_present_position(self.memory)

    # ---- writes and their side effects --------------------------------------------------------
    def write(self, address: int, payload: bytes) -> int:
        """Apply a bus write all-or-nothing; return the status error code (0 = success)."""
        memory = self.memory
        try:
            new, names = memory.plan_write(address, payload)
        except TableError as error:
            return error.code
        old_torque = memory.get('torque_enable')
        old_mode = memory.get('operating_mode')
        if 'torque_enable' in names and new[memory.table.torque_address]:
            if memory.get('hardware_error_status') & memory.get('shutdown'):
                return ErrorCode.RESULT_FAIL
        memory.commit(new)
        self._side_effects(self._as_roles(names), old_torque, old_mode)
        return 0

    def _as_roles(self, names: frozenset[str]) -> frozenset[str]:
        """
        Return the items written under the XM430 manual's names the side effects go by.

        Another table's own names get their roles (the AX's Moving Speed is goal_velocity, the
        XL-320's Control Mode operating_mode); a Protocol 1.0 table's CW/CCW Angle Limits are
        its mode too: the simulator's Operating Mode follows them.
        """
        model = self.model
        roles = {own: role for role, own in model.roles.items()}
        named = frozenset(roles.get(name, name) for name in names)
        if model.mode_register and model.mode_register in names:
            named |= {'operating_mode'}
        if not model.mode_register and named & {'min_position_limit', 'max_position_limit',
                                                TORQUE_MODE}:
            memory = self.memory
            mode = model.angle_limit_mode(
                memory.get('min_position_limit'), memory.get('max_position_limit'),
                memory.get(TORQUE_MODE) if memory.has(TORQUE_MODE) else 0)
            memory.set('operating_mode', modes.BY_NAME[mode].number)
            named |= {'operating_mode'}
        return named

    def _side_effects(self, names: frozenset[str], old_torque: int, old_mode: int) -> None:
        memory = self.memory
        dynamics = self.dynamics
        if 'operating_mode' in names and memory.get('operating_mode') != old_mode \
                and self.model.mode_register != 'operating_mode':
            # A wheel/joint switch (the XL-320, the Protocol 1.0 tables) resets nothing.
            dynamics.reinit_present_position(memory)
        elif 'operating_mode' in names and memory.get('operating_mode') != old_mode:
            memory.set('profile_velocity', 0)
            memory.set('profile_acceleration', 0)
            for goal, limit in memory.table.goals_from_limits:
                memory.set(goal, memory.get(limit))
            for name in modes.RESET_GAINS:
                memory.set(name, memory.item(name).initial)
            dynamics.reinit_present_position(memory)
        if 'drive_mode' in names:
            # Bit 0 turns the frame Present Position counts in (torque is off: EEPROM).
            dynamics.reinit_present_position(memory)
        if 'torque_enable' in names:
            torque = memory.get('torque_enable')
            if torque != old_torque:
                if torque:
                    dynamics.reinit_present_position(memory)
                    if memory.get('operating_mode') in modes.POSITION_NUMBERS:
                        # The dynamics holds the horn where it is at torque on; the register
                        # says so too, rather than showing a goal the servo is not heading for.
                        memory.set('goal_position', memory.get('present_position'))
                dynamics.on_torque(bool(torque), memory)
        if 'goal_position' in names:
            dynamics.on_goal_position(memory)
        if 'goal_velocity' in names:
            dynamics.on_goal_velocity(memory)
