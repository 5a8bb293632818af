"""
The cycle's goal write: the goals queued since the last cycle, one sync write per protocol.

Goals.take hands the queue over under its own lock (so every slot register goes out at its
latest goal); the servos with a goal slot are packed into one sync write at the slot's address,
the others get one per goal register. Only the goals, the link, the manager's lock and the
roster are touched here.
"""

from typing import Dict, List, Tuple

from dxl_servo_driver.bus import FRAMERS
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.goals import Goals, Pending

SyncWrite = Tuple[float, int, int, List[Tuple[int, bytes]]]   # protocol, address, length, data


class GoalWriter:
    """Writes the queued goals of a cycle (or of a service that writes at once)."""

    def __init__(self, ctx: Context, goals: Goals) -> None:
        self._lock = ctx.lock
        self._roster = ctx.roster
        self._link = ctx.link
        self._goals = goals

    def write_pending(self) -> int:
        """
        Write the goals queued since the last cycle: one sync write.

        Servos with a goal slot (write_mode indirect) are written together at the slot's
        address, as long as the longest goal that changed needs (a current goal of a
        current_based_position joint: the whole slot; a position goal: 4 bytes); the others
        (no slot, or write_mode per_register) get one sync write per goal register.
        """
        with self._lock:
            bus = self._link.bus
            if not self._goals.waiting() or bus is None:
                return 0
            by_id = self._roster.by_id
            written, writes, loose = self._goals.take(self._pack)
            for protocol, address, length, data in writes:
                bus.sync_write(address, length, data, FRAMERS[protocol])
            for register, goals in loose.items():
                # Grouped by protocol and where the register is: every X-series table has it
                # at the same address, but a table that differs is honoured.
                groups: Dict[Tuple[float, int, int], List[Tuple[int, bytes]]] = {}
                for sid, value in goals.items():
                    servo = by_id[sid]
                    item = servo.model.item(register)
                    groups.setdefault((servo.joint.protocol, item.address, item.size), []).append(
                        (sid, item.encode(value)))
                for (protocol, address, size), data in groups.items():
                    bus.sync_write(address, size, data, FRAMERS[protocol])
            return written

    def _pack(self, pending: Pending) -> Tuple[int, List[SyncWrite], Pending]:
        """
        Return (goals taken, the slot writes, the goals written per register) of the queue.

        Run by Goals.take under the queue's lock, so every slot register goes out at its
        latest goal.
        """
        by_id = self._roster.by_id
        needs: Dict[int, int] = {}   # servo id -> slot bytes its changed goals need
        loose: Pending = {}
        written = 0
        for register, goals in pending.items():
            written += len(goals)
            for sid, value in goals.items():
                servo = by_id[sid]
                slot = servo.goal_slot
                if slot is None or register not in slot.needs or not slot.holds(servo.goal_raw):
                    loose.setdefault(register, {})[sid] = value
                else:
                    needs[sid] = max(slot.needs[register], needs.get(sid, 0))
        return written, self._slot_writes(needs), loose

    def _slot_writes(self, needs: Dict[int, int]) -> List[SyncWrite]:
        """Return the sync writes (address, length, data) of the servos whose goals need a slot."""
        by_id = self._roster.by_id
        slotted = [(by_id[sid], need) for sid, need in needs.items()]
        # (protocol, slot address) -> the longest need there: one sync write each.
        lengths: Dict[Tuple[float, int], int] = {}
        for servo, need in slotted:
            key = (servo.joint.protocol,
                   servo.goal_slot.data_address)  # type: ignore[union-attr]
            lengths[key] = max(need, lengths.get(key, 0))
        writes: Dict[Tuple[float, int], List[Tuple[int, bytes]]] = {key: [] for key in lengths}
        for servo, _ in slotted:
            slot = servo.goal_slot
            assert slot is not None
            key = (servo.joint.protocol, slot.data_address)
            writes[key].append((servo.servo_id, slot.pack(servo.goal_raw, lengths[key])))
        return [(protocol, address, lengths[protocol, address], data)
                for (protocol, address), data in writes.items()]
