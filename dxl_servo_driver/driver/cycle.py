"""
The cycle on the bus: one packed state read of every servo, one sync write per goal register.

The read is a SYNC_READ or, with read_mode fast_sync (or auto, when every servo's firmware has
it), a FAST_SYNC_READ: one status packet for all servos instead of one each. Servos whose state
blocks lie at different addresses or lengths (a mixed bus: an X with an XL-320 or a P) are read
by one BULK_READ (FAST_BULK_READ likewise), each at its own, rather than one sync read each:
one request, one wait for the adapter. Servos on Protocol
1.0 (no sync read there) are read after it by one BULK_READ where every one of their models
has it, else one READ each; a 1.0-only bus reads them first and does not pipeline. A sample
without a Realtime Tick (the older tables) is tagged instead: its read starts up to
READ_TAGS - 1 bytes early, a different count each cycle, so a late reply of an earlier cycle
has another length and is refused (the bus reads on to the deadline whenever it is suspicious,
so two answers from one id are never taken; what is left is a late copy of the same length
standing in for a lost answer: one chance in READ_TAGS).

The read is dated so a late reply is never published as current, retried per servo within
the cycle's budget, and watched for servos that restarted on their own (their indirect map is
gone: the block reads zeros and the canary is 0), which are handed to recovery. A servo that
does not answer well keeps fresh False: left out of what is published, never given a stale
or invented value.
"""

from dataclasses import dataclass
import time
from typing import Any, Callable, Dict, List, Optional, Tuple, TypeVar, Union

from dxl_servo_driver import state_block
from dxl_servo_driver.bus import FRAMERS, READ_TAGS, SyncRead, SyncResult
from dxl_servo_driver.driver.context import Context, SharedLock
from dxl_servo_driver.driver.goals import Goals, Pending
from dxl_servo_driver.driver.servo import (
    BLOCK, IDX_HW_ERROR, IDX_TICK, IDX_TORQUE, Servo, Throttle)
from dxl_servo_driver.errors import CommError, StatusError
from dxl_servo_driver.protocol import READ_PACKET_SIZE, STATUS_OVERHEAD

_NO_HEALTH = (0,) * (len(BLOCK.names) - BLOCK.TAGGED_FIELDS)
T = TypeVar('T')
# A servo that missed this many sync reads in a row is not retried on its own in a cycle.
SILENT_AFTER_FAILURES = 3
# read_mode auto: this many Fast Sync Reads in a row with no part taken and it is given up.
FAST_EMPTY_LIMIT = 3
# The longest a read waits for those waiting for the lock to have it (a woken thread is
# scheduled within a millisecond, unless the machine is swamped: then the cycle goes on).
LET_IN_S = 0.02
_TAGGED = BLOCK.tagged_struct   # motion and tick are laid out alike on every model
_TAGGED_FIELDS = _TAGGED.format.lstrip('<')   # each servo's data in a whole-block decode
# A cycle's goal per servo as the bus limit counts it: a position (4 bytes; 2 on the Protocol
# 1.0 tables, whose goals are 2 bytes).
GOAL_BYTES = 4
# The tag a tickless block's read carries on average (the bus limit counts it).
_MEAN_TAG = (READ_TAGS - 1) // 2
GOAL_BYTES_1 = 2
SyncWrite = Tuple[float, int, int, List[Tuple[int, bytes]]]   # protocol, address, length, data


@dataclass(eq=False)
class _Ended:
    """A cycle read that ended as it began (a 1.0-only bus has no read to pipeline)."""

    result: SyncResult
    fast: bool = False

    def collect(self) -> SyncResult:
        """Return the result (the read is over)."""
        return self.result

    def abort(self) -> None:
        """Nothing is on the wire."""


# What Cycle._begin puts in a ReadInFlight: the read, its stamp, whole or not, its length, the
# servos a clean block decodes.
_Begun = Tuple[Union[SyncRead, _Ended], float, bool, int, List[Servo]]


@dataclass(eq=False)
class ReadInFlight:
    """
    The cycle's sync read on the wire, owning the manager's lock (and the bus's) until it ends.

    start() takes the manager's lock and puts the read on the wire; finish() (collect and
    process) or abort() ends it, once, in the same thread: this class is the only place that
    takes and releases the read's locks. In between, the caller may only do work that needs
    neither (publishing the last cycle).
    """

    _lock: SharedLock
    pending: Union[SyncRead, _Ended]
    stamp: float
    full: bool
    length: int
    servos: List[Servo]   # whose block a clean answer decodes, in order (as when it began)
    ended: bool = False

    @classmethod
    def start(cls, lock: SharedLock, begin: Callable[[], Optional[_Begun]]
              ) -> Optional['ReadInFlight']:
        """Take the lock and begin(); None (the lock released) when begin() read nothing."""
        lock.acquire()
        try:
            started = begin()
        except BaseException:
            lock.release()
            raise
        if started is None:
            lock.release()
            return None
        return cls(lock, *started)

    def finish(self, process: Callable[[SyncResult], T]) -> T:
        """Collect the answers, process them (the lock still held), release the lock."""
        if self.ended:
            raise RuntimeError('the read in flight ended already')
        self.ended = True
        try:
            return process(self.pending.collect())
        finally:
            self._lock.release()

    def abort(self) -> None:
        """Give the read up and release the locks (idempotent)."""
        if self.ended:
            return
        self.ended = True
        try:
            self.pending.abort()
        finally:
            self._lock.release()


class Cycle:
    """The state read and the goal write of every cycle, and their counters."""

    def __init__(self, ctx: Context, goals: Goals) -> None:
        self._ctx = ctx
        self._lock = ctx.lock
        self._roster = ctx.roster
        self._link = ctx.link
        self._tasks = ctx.tasks   # joints with a task in progress are left out of the read
        self._goals = goals
        self._stale = ctx.stale
        self._clock = ctx.clock
        self._warn_throttled = Throttle(ctx.log.warn, clock=ctx.clock)
        # Servos found restarted on their own by the last read: recovery takes them.
        self.restarted: List[Servo] = []
        self.cycles = 0
        self.read_failures = 0
        self.retries = 0
        self.retry_successes = 0
        # How often the whole state block (health part too) is read; the node sets it from
        # state_rate and the 1 Hz diagnostics.
        self.health_period_s = 0.1
        self._last_full_s = -1e9
        self._need_full = True
        self._ids: List[Tuple[Servo, int]] = []
        # Servos whose block is the X layout, read through indirect entries and tick-dated:
        # the usual cycle decodes them with one struct, the rest go the careful way.
        self._shaped: frozenset[int] = frozenset()
        self._block_servos: List[Servo] = []
        self._reading: Optional[ReadInFlight] = None
        # The sync reads: (block, ids) per state-block layout; one on most buses.
        self._groups: List[Tuple[state_block.StateBlock, List[int]]] = []
        # The servos on Protocol 1.0, read after the sync reads; the tag of their next read.
        self._group_1: List[Servo] = []
        self._bulk_1 = False
        self._bulk_2 = False
        self._tag = 0
        # Fast Sync Read: in use now; given up for good (read_mode auto) after fast reads in a
        # row that brought nothing back, counted here.
        self.fast = False
        self.fast_given_up = False
        self._fast_empty = 0
        # A sample refused as older than its request: the next read lingers to its deadline,
        # so a late answer taken in the place of one still on its way does not repeat.
        self._linger_next = False

    def want_full(self) -> None:
        """Read the whole block (health too) next cycle."""
        self._need_full = True

    def refresh(self) -> None:
        """Take who is read again (after configure, or a task began or ended)."""
        # The hot path reads these instead of rebuilding lists every cycle. A servo with a task
        # in progress (being restored, rebooted, probed) is left out of the cycle's read.
        self._ids = [(servo, servo.servo_id) for servo in self._roster.active()
                     if servo.name not in self._tasks]
        self._shaped = frozenset(
            servo_id for servo, servo_id in self._ids
            if not servo.block.direct and servo.block.has_tick
            and servo.block.tagged_struct.format == _TAGGED.format)
        groups: Dict[Tuple[int, int], Tuple[state_block.StateBlock, List[int]]] = {}
        self._group_1 = [servo for servo, _ in self._ids if servo.joint.protocol == 1.0]
        self._bulk_1 = all(servo.model.bulk_read for servo in self._group_1)
        for servo, servo_id in self._ids:
            if servo.joint.protocol == 1.0:
                continue
            block = servo.block
            groups.setdefault((block.read_address, block.size), (block, []))[1].append(servo_id)
        self._groups = sorted(groups.values(), key=lambda group: -len(group[1]))
        # Several layouts: one bulk read of all of them, each at its own address and length.
        self._bulk_2 = len(self._groups) > 1
        # One sync read of X-layout servos and nothing else: its usual clean block is decoded
        # whole by the bus (BlockTemplate), these servos in the order asked.
        self._block_servos = []
        if len(self._groups) == 1 and not self._group_1 and all(
                servo_id in self._shaped for servo_id in self._groups[0][1]):
            self._block_servos = [self._roster.by_id[servo_id] for servo_id in self._groups[0][1]]
        mode = self._ctx.config.read_mode
        self.fast = bool(self._groups) and (mode == 'fast_sync' or (
            mode == 'auto' and not self.fast_given_up
            and all(servo.model.has_fast_sync_read(servo.firmware_version)
                    for servo, _ in self._ids if servo.joint.protocol != 1.0)))

    def wire_plan(self) -> List[state_block.Transaction]:
        """
        Return the transactions of one usual cycle as the servos are grouped now.

        Each sync read (one per block layout; fast when in use), the Protocol 1.0 servos' bulk
        read or reads (a tickless block counted with its mean tag), and one sync write of a goal
        per servo in each protocol: what the bus-limit report and the diagnostics count.
        """
        plan: List[state_block.Transaction] = []
        if self._bulk_2:
            lengths = [_group_length(block, BLOCK.tagged_size, _MEAN_TAG)
                       for block, ids in self._groups for _ in ids]
            plan.append(state_block.Transaction(
                'fast bulk read' if self.fast else 'bulk read',
                (state_block.fast_bulk_read_bytes if self.fast else state_block.bulk_read_bytes)(
                    lengths), 1 if self.fast else len(lengths)))
        for block, ids in [] if self._bulk_2 else self._groups:
            length = _group_length(block, BLOCK.tagged_size, _MEAN_TAG)
            if self.fast:
                plan.append(state_block.Transaction(
                    'fast sync read', state_block.fast_sync_read_bytes(len(ids), length), 1))
            else:
                plan.append(state_block.Transaction(
                    'sync read', state_block.sync_read_bytes(len(ids), length), len(ids)))
        lengths = [_group_length(servo.block, BLOCK.tagged_size)
                   + (0 if servo.block.has_tick else _MEAN_TAG) for servo in self._group_1]
        if lengths and self._bulk_1:
            plan.append(state_block.Transaction(
                'bulk read (Protocol 1.0)', state_block.bulk_read_bytes_1(lengths), len(lengths)))
        else:
            plan.extend(state_block.Transaction('read (Protocol 1.0)',
                                                state_block.read_bytes_1(length), 1)
                        for length in lengths)
        on_2 = len(self._ids) - len(self._group_1)
        if on_2:
            plan.append(state_block.Transaction(
                'sync write', state_block.sync_write_bytes(on_2, GOAL_BYTES), 0))
        if self._group_1:
            plan.append(state_block.Transaction(
                'sync write (Protocol 1.0)',
                state_block.sync_write_bytes_1(len(self._group_1), GOAL_BYTES_1), 0))
        return plan

    # the read -----------------------------------------------------------------------------
    def begin_read(self, full: Optional[bool] = None,
                   stamp: Optional[Callable[[], None]] = None) -> bool:
        """
        Put the cycle's sync read on the wire and return; end_read() collects it.

        The read in flight (ReadInFlight) holds the manager's lock and the bus's until
        end_read() or abort_read(), in the same thread. False (nothing in flight, no lock held)
        when no servo is to be read. stamp: called once the lock is held, right before the
        read goes on the wire: a caller that stamped before waiting for the lock (held by a
        service's transaction, up to its deadlines) would date the samples too early.
        """
        # Called with the lock free: whoever waits for it (a service) has it first, or a cycle
        # running flat out would take it back before they are even woken.
        self._lock.let_waiting_in(LET_IN_S)
        self._reading = ReadInFlight.start(self._lock, lambda: self._begin(full, stamp))
        return self._reading is not None

    def _begin(self, full: Optional[bool],
               on_stamp: Optional[Callable[[], None]] = None) -> Optional[_Begun]:
        bus = self._link.io()
        if not self._groups and not self._group_1:
            return None
        if on_stamp is not None:
            on_stamp()
        stamp = self._clock()
        if full is None:
            full = stamp - self._last_full_s >= self.health_period_s or self._need_full
        # Every read carries the servo's Realtime Tick, which dates each sample: a reply has
        # nothing but its id and length to tie it to its request, and an adapter that hands
        # over an old reply late (in the place of one it lost) is caught by nothing else. The
        # whole block (health too) every health_period_s.
        length = BLOCK.size if full else BLOCK.tagged_size   # _group_length: per model
        self._tag = (self._tag + 1) % READ_TAGS
        if not self._groups:
            return _Ended(self._read_1(length)), stamp, full, length, []
        if self._bulk_2:
            records = [(servo_id, block.read_address, _group_length(block, length, self._tag))
                       for block, ids in self._groups for servo_id in ids]
            pending = bus.begin_bulk_read(records, self.fast, self._linger_next)
        else:
            block, ids = self._groups[0]
            whole = self._block_servos and length == BLOCK.tagged_size
            pending = bus.begin_sync_read(block.read_address,
                                          _group_length(block, length, self._tag), ids,
                                          self.fast, self._linger_next,
                                          _TAGGED_FIELDS if whole else '')
        self._linger_next = False
        return pending, stamp, full, length, self._block_servos

    def _read_1(self, length: int) -> SyncResult:
        """
        Read the Protocol 1.0 servos: one BULK_READ, or one READ each where a model lacks it.

        A block without a tick is read tagged (the module docstring): from `tag` bytes before
        it, as far as the table starts, and the tag's bytes are cut off again here.
        """
        bus = self._link.io()
        records = []
        cut: Dict[int, Tuple[int, int]] = {}
        for servo in self._group_1:
            block = servo.block
            size = _group_length(block, length)
            lead = 0 if block.has_tick else min(self._tag, block.read_address)
            records.append((servo.servo_id, block.read_address - lead, size + lead))
            cut[servo.servo_id] = (lead, size)
        if self._bulk_1:
            result = bus.bulk_read(records, FRAMERS[1.0])
        else:
            data: Dict[int, Union[bytes, CommError]] = {}
            dated: Dict[int, Tuple[float, float]] = {}
            sent_s = time.monotonic()
            for servo_id, address, size in records:
                try:
                    data[servo_id], asked_s = bus.read_dated(
                        servo_id, address, size, _linger(self._roster.by_id[servo_id].block))
                    dated[servo_id] = (asked_s, time.monotonic())
                except CommError as exc:
                    data[servo_id] = exc
            result = SyncResult(data, all(isinstance(each, bytes) for each in data.values()),
                                sent_s, dated=dated)
        for servo_id, (lead, size) in cut.items():
            answer = result.data.get(servo_id)
            if isinstance(answer, bytes) and lead:
                result.data[servo_id] = answer[lead:lead + size]
        return result

    def abort_read(self) -> None:
        """Give up the sync read in flight, if any, and release the locks (idempotent)."""
        reading, self._reading = self._reading, None
        if reading is not None:
            reading.abort()

    @property
    def reading(self) -> bool:
        """Return True while a cycle read is on the wire (begun, or chained by end_read)."""
        return self._reading is not None

    def end_read(self, retry_until: Optional[float] = None,
                 chain: Optional[Callable[[], None]] = None) -> float:
        """
        Collect the sync read begun by begin_read(); return its monotonic time.

        chain: when the block came back clean and nothing waits to go on the wire before the
        next read (_may_chain), put that read on the wire at once, before this one's samples are
        taken, calling chain() first (the caller's stamp of it): the cycle's bus time is not
        held up by the taking. `reading` then says a read is in flight, and the caller writes
        nothing until it collected it.
        """
        reading, self._reading = self._reading, None
        if reading is None:
            raise RuntimeError('end_read() without a read in flight')
        return reading.finish(lambda result: self._taken(reading, result, retry_until, chain))

    def _taken(self, reading: ReadInFlight, result: SyncResult,
               retry_until: Optional[float], chain: Optional[Callable[[], None]] = None) -> float:
        """Complete a cycle's read: the other layouts, retries, samples taken (lock held)."""
        received = time.monotonic()   # the bus dates requests on this clock
        if result.values is not None:
            # The usual cycle: one clean block, every servo decoded at once by the bus.
            if chain is not None and self._may_chain(result.values, reading.servos):
                # The lock is taken again (re-entrant): released by this read's finish, it stays
                # with the next one until that ends. chain() is its stamp, as begin_read's.
                self._reading = ReadInFlight.start(self._lock, lambda: self._begin(None, chain))
            self._fast_empty = 0
            self._need_full = False
            refused = self._stale.refused
            self._take_block(result, reading.stamp, received, reading.servos)
            self._after_dating(refused)
            return reading.stamp
        bus = self._link.io()
        for block, ids in [] if self._bulk_2 else self._groups[1:]:
            # Models whose state block lives elsewhere (an X330 before firmware 53): one more
            # sync read each layout, dated on their own.
            _merge(result, ids, bus.sync_read(
                block.read_address, _group_length(block, reading.length, self._tag), ids,
                reading.pending.fast))
        if self._groups and self._group_1:
            _merge(result, [servo.servo_id for servo in self._group_1],
                   self._read_1(reading.length))
        fast_parts = -1
        if reading.pending.fast:
            fast_parts = sum(isinstance(data, bytes) for data in result.data.values())
        if retry_until is not None and self._ctx.config.read_retries and not result.clean:
            self._retry_failed(result, reading.length, retry_until)
        if fast_parts >= 0:
            self._judge_fast(fast_parts, result)
        self._need_full = False
        if reading.full:
            self._last_full_s = reading.stamp
        refused = self._stale.refused
        self._take_results(result, reading.stamp, received)
        self._after_dating(refused)
        return reading.stamp

    def _after_dating(self, refused_before: int) -> None:
        """End a cycle's read: a sample refused as older than its request tells of a late reply."""
        self._linger_next = self._stale.refused > refused_before
        if self._linger_next:
            # It was taken in the place of this read's own, which came after its deadline: the
            # next read lingers to get back in step, and the deadlines get more slack.
            self._link.io().raise_slack()
        self.cycles += 1

    def _judge_fast(self, fast_parts: int, result: SyncResult) -> None:
        """
        read_mode auto: give Fast Sync Read up when it brings nothing back but servos answer.

        Silence alone proves nothing (servos off, cable out); a fast read with no part taken
        while the same servos then answered their one-off retries does: firmware or adapter
        that do not do Fast Sync Read.
        """
        if fast_parts:
            self._fast_empty = 0
            return
        if not result.dated:
            return
        self._fast_empty += 1
        if self._ctx.config.read_mode == 'auto' and self._fast_empty >= FAST_EMPTY_LIMIT:
            self.fast = False
            self.fast_given_up = True
            self._warn_throttled(
                'fast', f'read_mode auto: {FAST_EMPTY_LIMIT} fast sync reads in a row brought '
                'nothing back while the servos answered on their own; sync reads from now on '
                '(until the next configure)')

    def _may_chain(self, values: Tuple[int, ...], servos: List[Servo]) -> bool:
        """
        Return True when the next read may go on the wire before this block is taken.

        Nothing may wait to be written before it (goals, a task's steps, a pair's torque-off:
        none while a read is in flight), nobody may wait for the lock (a chained read keeps
        it), and the block must be taken without a transaction (every servo known, no motion
        part of all zeros, which _take_one reads again to tell a restart). What the cycle's
        write also does (command timeouts, hardware-error recovery) still runs at every cycle
        that does not chain: every whole-block read (the health part, at least once a second),
        every cycle with a goal.
        """
        if (self._goals.waiting() or not self._tasks.idle or self._roster.secondary
                or self._lock.waiting):
            return False
        fields = BLOCK.TAGGED_FIELDS
        for index, servo in enumerate(servos):
            start = index * fields
            if servo.state is None or not (values[start] or values[start + 1]
                                           or values[start + 2]):
                return False
        return True

    def _take_block(self, result: SyncResult, stamp: float, received: float,
                    servos: List[Servo]) -> None:
        """
        Take a block the bus decoded whole: each servo's motion and tick, dated, in order.

        What _take_results does for a well servo's usual sample, without a look-up, a decode or
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
                self._take_one(servo, servo.servo_id, result.template.data(result.block, index),
                               result, stamp, received)
                continue
            if servo.tick.check(sample[IDX_TICK], sent_s, received):
                servo.state = sample + state[fields:]
                servo.fresh = True
                servo.consecutive_failures = 0
            else:
                refuse(servo)

    def _take_results(self, result: SyncResult, stamp: float, received: float) -> None:
        get = result.data.get
        alerts = result.alerts
        dated = result.dated
        sent_s = result.sent_s
        check = self._stale.check
        tagged_size = BLOCK.tagged_size
        unpack_tagged = _TAGGED.unpack
        shaped = self._shaped
        for servo, servo_id in self._ids:
            data = get(servo_id)
            state = servo.state
            if isinstance(data, bytes) and len(data) == tagged_size and state is not None \
                    and servo_id in shaped:
                # The usual cycle: motion and tick of a servo known to be well, dated.
                values = unpack_tagged(data)
                if values[0] or values[1] or values[2]:   # all zeros: see _take_one
                    when = dated.get(servo_id)
                    if when is None:
                        fresh = check(servo, values[IDX_TICK], sent_s, received)
                    else:
                        fresh = check(servo, values[IDX_TICK], when[0], when[1])
                    if not fresh:
                        continue
                    servo.state = values + state[BLOCK.TAGGED_FIELDS:]
                    if alerts.get(servo_id) and not state[IDX_HW_ERROR]:
                        self._need_full = True   # a new hardware error: decode it next cycle
                    servo.fresh = True
                    servo.consecutive_failures = 0
                    continue
            if not isinstance(data, bytes):
                self._read_failed(servo, data)
                continue
            self._take_one(servo, servo_id, data, result, stamp, received)

    def _take_one(self, servo: Servo, servo_id: int, data: bytes, result: SyncResult,
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
            checked = self._check_restart(servo)
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
            self._need_full = True
        if alerts.get(servo_id) and not servo.state[IDX_HW_ERROR]:  # type: ignore
            self._need_full = True   # a new hardware error: decode it next cycle
        servo.fresh = True
        servo.consecutive_failures = 0

    def _read_failed(self, servo: Servo, error: Any) -> None:
        servo.fresh = False
        servo.comm_errors += 1
        servo.consecutive_failures += 1
        self.read_failures += 1
        self._warn_throttled(f'read:{servo.name}', f'joint {servo.name!r}: state read failed: '
                             f'{error}')

    def _check_restart(self, servo: Servo) -> Optional[Tuple[int, ...]]:
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
            self._read_failed(servo, exc)
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

    def _retry_failed(self, result: SyncResult, length: int, until: float) -> None:
        bus = self._link.io()
        # A retry always reads the tick: the bus is suspicious after a failure.
        length = max(length, BLOCK.tagged_size)
        one_read_s = bus.reply_timeout_s(STATUS_OVERHEAD + length, 1, READ_PACKET_SIZE)
        silent = {servo.servo_id for servo, _ in self._ids
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
                        servo_id, block.read_address, _group_length(block, length),
                        _linger(block))
                except CommError as exc:
                    result.data[servo_id] = exc
                    continue
                self.retry_successes += 1
                result.data[servo_id] = answer
                result.dated[servo_id] = (sent_s, time.monotonic())
                break

    # the write ----------------------------------------------------------------------------
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


def _merge(result: SyncResult, ids: List[int], more: SyncResult) -> None:
    """Add a later read's answers to the cycle's, each dated by that read (sent, received)."""
    got = time.monotonic()
    result.data.update(more.data)
    result.alerts.update(more.alerts)
    result.dated.update({servo_id: (more.sent_s, got) for servo_id in ids})
    result.dated.update(more.dated)
    result.clean = result.clean and more.clean


def _linger(block: state_block.StateBlock) -> Optional[bool]:
    """
    Return read_dated's linger for a block: a ticked one never reads on (its tick dates it).

    One without a tick reads on to the deadline when the bus is suspicious (None): nothing else
    tells its answer from a late one.
    """
    return False if block.has_tick else None


def _group_length(block: state_block.StateBlock, length: int, tag: int = 0) -> int:
    """
    Return the read length of a model's block for a read of length bytes of the shape.

    The whole block, its tagged part or its motion part as that model lays them out (a table
    without a tick has no tick to read); a block without a tick is read tag bytes further
    (within the block), so its length tells this cycle's answer from a late one of another.
    """
    if block.direct or length >= BLOCK.size:
        return block.size
    part = (block.tagged_size if length == BLOCK.tagged_size else
            block.motion_size if length == BLOCK.motion_size else length)
    return part if block.has_tick else min(block.size, part + tag)
