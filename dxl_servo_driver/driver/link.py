"""
Transactions outside the cycle on one servo: retried, confirmed, dated, verified.

The link holds the open Bus (None while the port is closed) and is where the driver's
one-off transactions go: a lost or corrupted reply is tried again, a value the servo changes
by itself is dated with its Realtime Tick so a late reply never passes for it, and a write that
matters is read back. A stop request is honoured between two attempts.
"""

from contextlib import contextmanager
import time
from typing import Any, Callable, Iterator, Optional, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.driver.servo import Servo, StaleGuard
from dxl_servo_driver.driver.state_block import GOAL_SLOT_SIZE, GoalSlot
from dxl_servo_driver.errors import CommError, CommTimeout, CorruptReply, Interrupted
from dxl_servo_driver.models import Item

# A changing register this close to the Realtime Tick is read with it, to date the reply.
DATED_SPAN_BYTES = 64
# Configure and activate try a transaction for this long at least (and ping_retries times):
# nothing runs yet that a wait would hold up, and a busy computer (or a simulator sharing it)
# can hold replies up past a bus's deadlines several times in a row. A servo that is really
# missing costs a start-up this much.
START_PATIENCE_S = 1.0


def changes_by_itself(item: Item) -> bool:
    """Return True for registers the servo changes (present values, tick, flags, errors)."""
    return item.area == 'ram' and (item.access == 'R' or item.name.startswith('indirect_data'))


class Link:
    """The open bus and the one-off transactions on one servo."""

    def __init__(self, attempts: int, should_stop: Callable[[], bool],
                 stale: StaleGuard) -> None:
        self.bus: Optional[Bus] = None
        # The adapter's latency timer as configure found it (driver/adapter.py), which the bus
        # limit counts; None until found (then the bus's timer in force is counted).
        self.adapter_latency_s: Optional[float] = None
        # Asked between attempts: a signal stops configure and activate promptly.
        self.should_stop = should_stop
        self._attempts = attempts
        self._patience_s = 0.0
        self._stale = stale

    def io(self) -> Bus:
        """Return the open bus; CommError when the port is closed."""
        if self.bus is None:
            raise CommError('the bus is not open (the node is not configured)')
        return self.bus

    @contextmanager
    def uninterruptible(self) -> Iterator[None]:
        """Run a block that a stop request must not cut short (the torque-off at the end)."""
        stop, self.should_stop = self.should_stop, lambda: False
        try:
            yield
        finally:
            self.should_stop = stop

    @contextmanager
    def patient(self, patience_s: float = START_PATIENCE_S) -> Iterator[None]:
        """Run a block whose transactions are tried for patience_s at least (see above)."""
        before, self._patience_s = self._patience_s, patience_s
        try:
            yield
        finally:
            self._patience_s = before

    def attempt(self, action: Callable[[], Any]) -> Any:
        """
        Run a transaction, again on a lost or corrupted reply.

        ping_retries times in all, and inside patient() for its patience at least.
        """
        give_up_s = time.monotonic() + self._patience_s
        tries = 0
        while True:
            if self.should_stop():
                raise Interrupted('stop requested')
            tries += 1
            try:
                return action()
            except (CommTimeout, CorruptReply):
                if tries >= self._attempts and time.monotonic() >= give_up_s:
                    raise

    def read(self, servo: Servo, name: str) -> int:
        """Read a register: confirmed when it holds still, dated when it changes by itself."""
        bus = self.io()
        item = servo.model.item(name)
        if not changes_by_itself(item):
            # Confirmed by a second read: a late reply cannot pass for the value.
            return int(self.attempt(lambda: bus.read_item(servo.servo_id, item)))
        return int(self.attempt(lambda: self._read_dated(servo, item)))

    def _read_dated(self, servo: Servo, item: Item) -> int:
        """Read a value that changes by itself with the Realtime Tick, refusing a late reply."""
        bus = self.io()
        if not servo.model.has('realtime_tick'):
            # A table without a tick (the XL-320): the bus's own checks are all there is.
            return item.decode(bus.read(servo.servo_id, item.address, item.size, confirm=False))
        tick = servo.model.item('realtime_tick')
        start = min(tick.address, item.address)
        end = max(tick.address + tick.size, item.address + item.size)
        if end - start > DATED_SPAN_BYTES:
            # Too far from the tick to read both in one go: the length tag is the guard.
            data = bus.read(servo.servo_id, item.address, item.size, confirm=False)
            return item.decode(data)
        data, sent_s = bus.read_fresh(servo.servo_id, start, end - start)
        at = tick.address - start
        if not self._stale.check(servo, int.from_bytes(data[at:at + tick.size], 'little'),
                                 sent_s, time.monotonic()):
            raise CorruptReply(f'id {servo.servo_id}: a reply older than its request '
                               '(refused)', servo.servo_id)
        at = item.address - start
        return item.decode(data[at:at + item.size])

    def write(self, servo: Servo, name: str, value: int) -> None:
        """Write a register, keeping what the servo's record says about it."""
        bus = self.io()
        item = servo.model.item(name)
        if name == 'torque_enable' and value:
            servo.torque_maybe_on = True   # before: the write may land even if its reply is lost
        self.attempt(lambda: bus.write_item(servo.servo_id, item, value))
        if name == 'torque_enable' and not value:
            servo.torque_maybe_on = False
        elif name == 'homing_offset':
            servo.homing_offset = value

    def write_verified(self, servo: Servo, name: str, value: int) -> None:
        """Write a register and read it back; CommError when it does not hold the value."""
        self.write(servo, name, value)
        read_back = self.read(servo, name)
        if read_back != value:
            raise CommError(f'joint {servo.name!r}: {name} reads back {read_back} after '
                            f'writing {value}', servo.servo_id)

    def ping(self, servo: Servo) -> int:
        """Ping (tried again on a lost reply); return the model number."""
        bus = self.io()
        return int(self.attempt(lambda: bus.ping(servo.servo_id)))

    def ping_once(self, servo: Servo) -> None:
        """Ping once: the caller decides what a lost reply means (a booting servo)."""
        self.io().ping(servo.servo_id, probe=True)

    def reboot(self, servo: Servo) -> None:
        """Send REBOOT."""
        bus = self.io()
        self.attempt(lambda: bus.reboot(servo.servo_id))

    def clear_multi_turn(self, servo: Servo) -> None:
        """Send CLEAR (multi-turn): Present Position back within one turn."""
        bus = self.io()
        self.attempt(lambda: bus.clear_multi_turn(servo.servo_id))

    def write_indirect_map(self, servo: Servo, slot: Optional[GoalSlot] = None) -> None:
        """Write the indirect map of the servo's state block (and goal slot, right after it)."""
        bus = self.io()
        block = servo.block
        if block.direct:
            return   # read at its own registers: nothing to map
        data = block.indirect_map_bytes()
        if slot is not None:
            if slot.map_address != block.indirect_map_address() + len(data):
                raise ValueError('the goal slot does not follow the state block')
            data += slot.map_bytes()
        self.attempt(lambda: bus.write(servo.servo_id, block.indirect_map_address(), data))

    def write_slot_map(self, servo: Servo, slot: GoalSlot) -> None:
        """Map the goal slot to the goal registers of its mode."""
        bus = self.io()
        self.attempt(lambda: bus.write(servo.servo_id, slot.map_address, slot.map_bytes()))

    def slot_mapped(self, servo: Servo, slot: GoalSlot) -> bool:
        """Return whether the servo's goal slot entries hold the slot's map (read back)."""
        bus = self.io()
        expected = slot.map_bytes()
        return bool(self.attempt(
            lambda: bus.read(servo.servo_id, slot.map_address, len(expected))) == expected)

    def write_slot(self, servo: Servo, slot: GoalSlot) -> None:
        """Write the servo's goals (servo.goal_raw) through its whole goal slot."""
        bus = self.io()
        data = slot.pack(servo.goal_raw, GOAL_SLOT_SIZE)
        self.attempt(lambda: bus.write(servo.servo_id, slot.data_address, data))

    def read_block(self, servo: Servo) -> Tuple[int, ...]:
        """Read the whole state block once, fresh (a probe: no retry)."""
        block = servo.block
        return block.decode(self.io().read_fresh(servo.servo_id, block.read_address,
                                                 block.size)[0])
