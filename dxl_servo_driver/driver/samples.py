"""
Taking a cycle's samples: each servo's answer dated, decoded, judged; failures counted, retried.

The usual clean block the bus decoded whole is taken in order with no look-up (take_block);
anything else servo by servo (take_results): the usual sample of a servo known to be well by
one struct, the rest the careful way (take_one: any part, any layout, the restart checks). A
sample older than its request is refused (StaleGuard), a servo found restarted on its own is
kept in `restarted` for recovery, and a servo that does not answer well keeps fresh False: left
out of what is published, never given a stale or invented value. Failed servos are read again
alone while the cycle has time (retry_failed). need_full says the next read must be whole (a
new hardware error to decode, a servo's health not known yet).
"""

import time
from typing import Any, List, Optional, Tuple

from dxl_servo_driver.bus import SyncResult
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.read_plan import group_length, linger, ReadPlan, TAGGED
from dxl_servo_driver.driver.servo import (
    BLOCK, IDX_HW_ERROR, IDX_TICK, IDX_TORQUE, Servo, Throttle)
from dxl_servo_driver.errors import CommError, StatusError
from dxl_servo_driver.protocol import READ_PACKET_SIZE, STATUS_OVERHEAD

_NO_HEALTH = (0,) * (len(BLOCK.names) - BLOCK.TAGGED_FIELDS)
# A servo that missed this many sync reads in a row is not retried on its own in a cycle.
SILENT_AFTER_FAILURES = 3


class Samples:
    """The samples of a cycle's read taken into the servos, and what their taking counted."""

    def __init__(self, ctx: Context, plan: ReadPlan) -> None:
        self._ctx = ctx
        self._roster = ctx.roster
        self._link = ctx.link
        self._stale = ctx.stale
        self._clock = ctx.clock
        self._plan = plan
        self._warn_throttled = Throttle(ctx.log.warn, clock=ctx.clock)
        # Servos found restarted on their own by the last read: recovery takes them.
        self.restarted: List[Servo] = []
        self.read_failures = 0
        self.retries = 0
        self.retry_successes = 0
        # The next read reads the whole block (health too).
        self.need_full = True

    def take_block(self, result: SyncResult, stamp: float, received: float,
                   servos: List[Servo]) -> None:
        """
        Take a block the bus decoded whole: each servo's motion and tick, dated, in order.

        What take_results does for a well servo's usual sample, without a look-up, a decode or
        a length check per servo (the bus checked the block); a servo whose sample needs more
        (no state yet, a motion part of all zeros) goes the careful way with its bytes.
        """
        values = result.values
        assert values is not None and result.template is not None
        refuse = self._stale.refuse
        sent_s = result.sent_s
        fields = BLOCK.TAGGED_FIELDS
        start = 0
        for index, servo in enumerate(servos):
            sample = values[start:start + fields]
            start += fields
            state = servo.state
            if state is None or not (sample[0] or sample[1] or sample[2]):
                self.take_one(servo, servo.servo_id, result.template.data(result.block, index),
                              result, stamp, received)
                continue
            if servo.tick.check(sample[IDX_TICK], sent_s, received):
                servo.state = sample + state[fields:]
                servo.fresh = True
                servo.consecutive_failures = 0
            else:
                refuse(servo)

    def take_results(self, result: SyncResult, stamp: float, received: float) -> None:
        """Take every servo's answer of a read not decoded whole (any layout, retries merged)."""
        get = result.data.get
        alerts = result.alerts
        dated = result.dated
        sent_s = result.sent_s
        check = self._stale.check
        tagged_size = BLOCK.tagged_size
        unpack_tagged = TAGGED.unpack
        shaped = self._plan.shaped
        for servo, servo_id in self._plan.ids:
            data = get(servo_id)
            state = servo.state
            if isinstance(data, bytes) and len(data) == tagged_size and state is not None \
                    and servo_id in shaped:
                # The usual cycle: motion and tick of a servo known to be well, dated.
                values = unpack_tagged(data)
                if values[0] or values[1] or values[2]:   # all zeros: see take_one
                    when = dated.get(servo_id)
                    if when is None:
                        fresh = check(servo, values[IDX_TICK], sent_s, received)
                    else:
                        fresh = check(servo, values[IDX_TICK], when[0], when[1])
                    if not fresh:
                        continue
                    servo.state = values + state[BLOCK.TAGGED_FIELDS:]
                    if alerts.get(servo_id) and not state[IDX_HW_ERROR]:
                        self.need_full = True   # a new hardware error: decode it next cycle
                    servo.fresh = True
                    servo.consecutive_failures = 0
                    continue
            if not isinstance(data, bytes):
                self.read_failed(servo, data)
                continue
            self.take_one(servo, servo_id, data, result, stamp, received)

    def take_one(self, servo: Servo, servo_id: int, data: bytes, result: SyncResult,
                 stamp: float, received: float) -> None:
        """Take one servo's sample the careful way: any part, any layout, restart checks."""
        check = self._stale.check
        alerts = result.alerts
        size = len(data)   # a retry may have read more than the sync read
        block = servo.block
        values = block.decoder(size)(data)
        full = size == block.size
        if not values[0] and not values[1] and not values[2] and not full \
                and block.has_canary:
            # What a restarted servo returns (its indirect map is gone) - or a horn at
            # exactly -pi, at rest: ask for the whole block, canary included, to know.
            checked = self.check_restart(servo)
            if checked is None:
                return
            values = checked
            full = True
        elif full and (block.restarted(values) or (
                not block.has_canary and servo.torque_wanted and servo.state is not None
                and not values[IDX_TORQUE] and not values[IDX_HW_ERROR]
                and not alerts.get(servo_id))):
            # No canary (a map that survives a reboot, or none): a servo whose torque went
            # off with no error to say why lost its power (or was rebooted by another).
            servo.fresh = False
            self.restarted.append(servo)
            return
        else:
            when = result.dated.get(servo_id, (result.sent_s, received))
            if block.has_tick and not check(servo, values[IDX_TICK], when[0], when[1]):
                return
        if full:
            servo.state = values
            servo.health_time = stamp
        elif servo.state is not None:
            servo.state = values[:BLOCK.TAGGED_FIELDS] + servo.state[BLOCK.TAGGED_FIELDS:]
        else:
            # Motion is good; the health part is not known yet (health_time 0).
            servo.state = values[:BLOCK.TAGGED_FIELDS] + _NO_HEALTH
            self.need_full = True
        if alerts.get(servo_id) and not servo.state[IDX_HW_ERROR]:  # type: ignore
            self.need_full = True   # a new hardware error: decode it next cycle
        servo.fresh = True
        servo.consecutive_failures = 0

    def read_failed(self, servo: Servo, error: Any) -> None:
        """Count a servo's failed read and say it (throttled); its sample is not fresh."""
        servo.fresh = False
        servo.comm_errors += 1
        servo.consecutive_failures += 1
        self.read_failures += 1
        self._warn_throttled(f'read:{servo.name}', f'joint {servo.name!r}: state read failed: '
                             f'{error}')

    def check_restart(self, servo: Servo) -> Optional[Tuple[int, ...]]:
        """
        Read the whole block of a servo whose motion read was all zeros.

        Returns the block when the servo did not restart; None when it did (its restore is
        then started) or when it did not answer.
        """
        bus = self._link.io()
        try:
            data, sent_s = bus.read_dated(servo.servo_id, servo.block.read_address,
                                          servo.block.size)
        except CommError as exc:
            self.read_failed(servo, exc)
            return None
        values = servo.block.decode(data)
        if servo.block.restarted(values):
            servo.fresh = False
            self.restarted.append(servo)
            return None
        if servo.block.has_tick and not self._stale.check(servo, values[IDX_TICK], sent_s,
                                                          time.monotonic()):
            return None
        return values

    def retry_failed(self, result: SyncResult, length: int, until: float) -> None:
        """Read each servo that failed again on its own while the clock is before until."""
        bus = self._link.io()
        # A retry always reads the tick: the bus is suspicious after a failure.
        length = max(length, BLOCK.tagged_size)
        one_read_s = bus.reply_timeout_s(STATUS_OVERHEAD + length, 1, READ_PACKET_SIZE)
        silent = {servo.servo_id for servo, _ in self._plan.ids
                  if servo.consecutive_failures >= SILENT_AFTER_FAILURES}
        for servo_id, data in list(result.data.items()):
            if isinstance(data, (bytes, StatusError)):
                continue   # a status error is the servo's answer: asking again changes nothing
            if servo_id in silent:
                continue   # gone for now: the sync read keeps asking; retries serve the others
            for _ in range(self._ctx.config.read_retries):
                if self._clock() + one_read_s > until:
                    break
                self.retries += 1
                try:
                    block = self._roster.by_id[servo_id].block
                    answer, sent_s = bus.read_dated(
                        servo_id, block.read_address, group_length(block, length),
                        linger(block))
                except CommError as exc:
                    result.data[servo_id] = exc
                    continue
                self.retry_successes += 1
                result.data[servo_id] = answer
                result.dated[servo_id] = (sent_s, time.monotonic())
                break
