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

Its parts, each a module: who is read and how (read_plan.ReadPlan: refresh, wire_plan, read_mode
auto's judgement of fast reads), taking the samples (samples.Samples: dating, decoding, restart
checks, retries, counters) and the goal write (goal_write.GoalWriter). Here: the read in flight
(ReadInFlight, holding the manager's lock and the bus's from begin_read to end_read or
abort_read), whether the next read may be chained, and the Cycle the manager and the other parts
call, which puts them together.
"""

from dataclasses import dataclass
import time
from typing import Callable, Dict, List, Optional, Tuple, TypeVar, Union

from dxl_servo_driver.bus import FRAMERS, READ_TAGS, SyncRead, SyncResult
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.context import Context, SharedLock
from dxl_servo_driver.driver.goal_write import GoalWriter
from dxl_servo_driver.driver.goals import Goals
from dxl_servo_driver.driver.read_plan import (
    FAST_EMPTY_LIMIT, group_length, linger, ReadPlan, TAGGED_FIELDS)
from dxl_servo_driver.driver.samples import Samples, SILENT_AFTER_FAILURES
from dxl_servo_driver.driver.servo import BLOCK, Servo
from dxl_servo_driver.errors import CommError

__all__ = ['Cycle', 'FAST_EMPTY_LIMIT', 'LET_IN_S', 'ReadInFlight', 'SILENT_AFTER_FAILURES']

T = TypeVar('T')
# The longest a read waits for those waiting for the lock to have it (a woken thread is
# scheduled within a millisecond, unless the machine is swamped: then the cycle goes on).
LET_IN_S = 0.02


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
    """
    The state read and the goal write of every cycle, and their counters.

    The read is this class's own (begin_read, end_read, abort_read: the read in flight, its
    chaining); who is read comes from the ReadPlan, the samples are taken by Samples, the goals
    written by GoalWriter. The counters and flags the manager reads are theirs, said here.
    """

    def __init__(self, ctx: Context, goals: Goals) -> None:
        self._ctx = ctx
        self._lock = ctx.lock
        self._link = ctx.link
        self._goals = goals
        # The read's plan and its samples: their counters and flags (fast, restarted,
        # read_failures, retries) are what the manager reads of the cycle.
        self.plan = ReadPlan(ctx)
        self.samples = Samples(ctx, self.plan)
        self._writer = GoalWriter(ctx, goals)
        self.cycles = 0
        # How often the whole state block (health part too) is read; the node sets it from
        # state_rate and the 1 Hz diagnostics.
        self.health_period_s = 0.1
        self._last_full_s = -1e9
        self._reading: Optional[ReadInFlight] = None
        # The tag of the next read of a block without a tick (the module docstring).
        self._tag = 0
        # A sample refused as older than its request: the next read lingers to its deadline,
        # so a late answer taken in the place of one still on its way does not repeat.
        self._linger_next = False

    # what the others read and call --------------------------------------------------------
    def want_full(self) -> None:
        """Read the whole block (health too) next cycle."""
        self.samples.need_full = True

    def refresh(self) -> None:
        """Take who is read again (after configure, or a task began or ended)."""
        self.plan.refresh()

    def wire_plan(self) -> List[state_block.Transaction]:
        """Return the transactions of one usual cycle as the servos are grouped now."""
        return self.plan.wire_plan()

    def write_pending(self) -> int:
        """Write the goals queued since the last cycle (GoalWriter.write_pending)."""
        return self._writer.write_pending()

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
        plan = self.plan
        if not plan.groups and not plan.group_1:
            return None
        if on_stamp is not None:
            on_stamp()
        stamp = self._ctx.clock()
        if full is None:
            full = stamp - self._last_full_s >= self.health_period_s or self.samples.need_full
        # Every read carries the servo's Realtime Tick, which dates each sample: a reply has
        # nothing but its id and length to tie it to its request, and an adapter that hands
        # over an old reply late (in the place of one it lost) is caught by nothing else. The
        # whole block (health too) every health_period_s.
        length = BLOCK.size if full else BLOCK.tagged_size   # group_length: per model
        self._tag = (self._tag + 1) % READ_TAGS
        if not plan.groups:
            return _Ended(self._read_1(length)), stamp, full, length, []
        if plan.bulk_2:
            records = [(servo_id, block.read_address, group_length(block, length, self._tag))
                       for block, ids in plan.groups for servo_id in ids]
            pending = bus.begin_bulk_read(records, plan.fast, self._linger_next)
        else:
            block, ids = plan.groups[0]
            whole = plan.block_servos and length == BLOCK.tagged_size
            pending = bus.begin_sync_read(block.read_address,
                                          group_length(block, length, self._tag), ids,
                                          plan.fast, self._linger_next,
                                          TAGGED_FIELDS if whole else '')
        self._linger_next = False
        return pending, stamp, full, length, plan.block_servos

    def _read_1(self, length: int) -> SyncResult:
        """
        Read the Protocol 1.0 servos: one BULK_READ, or one READ each where a model lacks it.

        A block without a tick is read tagged (the module docstring): from `tag` bytes before
        it, as far as the table starts, and the tag's bytes are cut off again here.
        """
        bus = self._link.io()
        records = []
        cut: Dict[int, Tuple[int, int]] = {}
        for servo in self.plan.group_1:
            block = servo.block
            size = group_length(block, length)
            lead = 0 if block.has_tick else min(self._tag, block.read_address)
            records.append((servo.servo_id, block.read_address - lead, size + lead))
            cut[servo.servo_id] = (lead, size)
        if self.plan.bulk_1:
            result = bus.bulk_read(records, FRAMERS[1.0])
        else:
            data: Dict[int, Union[bytes, CommError]] = {}
            dated: Dict[int, Tuple[float, float]] = {}
            sent_s = time.monotonic()
            for servo_id, address, size in records:
                try:
                    data[servo_id], asked_s = bus.read_dated(
                        servo_id, address, size, linger(self._ctx.roster.by_id[servo_id].block))
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
        plan, samples = self.plan, self.samples
        if result.values is not None:
            # The usual cycle: one clean block, every servo decoded at once by the bus.
            if chain is not None and self._may_chain(result.values, reading.servos):
                # The lock is taken again (re-entrant): released by this read's finish, it stays
                # with the next one until that ends. chain() is its stamp, as begin_read's.
                self._reading = ReadInFlight.start(self._lock, lambda: self._begin(None, chain))
            plan.fast_empty = 0
            samples.need_full = False
            refused = self._ctx.stale.refused
            samples.take_block(result, reading.stamp, received, reading.servos)
            self._after_dating(refused)
            return reading.stamp
        bus = self._link.io()
        for block, ids in [] if plan.bulk_2 else plan.groups[1:]:
            # Models whose state block lives elsewhere (an X330 before firmware 53): one more
            # sync read each layout, dated on their own.
            _merge(result, ids, bus.sync_read(
                block.read_address, group_length(block, reading.length, self._tag), ids,
                reading.pending.fast))
        if plan.groups and plan.group_1:
            _merge(result, [servo.servo_id for servo in plan.group_1],
                   self._read_1(reading.length))
        fast_parts = -1
        if reading.pending.fast:
            fast_parts = sum(isinstance(data, bytes) for data in result.data.values())
        if retry_until is not None and self._ctx.config.read_retries and not result.clean:
            samples.retry_failed(result, reading.length, retry_until)
        if fast_parts >= 0:
            plan.judge_fast(fast_parts, result)
        samples.need_full = False
        if reading.full:
            self._last_full_s = reading.stamp
        refused = self._ctx.stale.refused
        samples.take_results(result, reading.stamp, received)
        self._after_dating(refused)
        return reading.stamp

    def _after_dating(self, refused_before: int) -> None:
        """End a cycle's read: a sample refused as older than its request tells of a late reply."""
        self._linger_next = self._ctx.stale.refused > refused_before
        if self._linger_next:
            # It was taken in the place of this read's own, which came after its deadline: the
            # next read lingers to get back in step, and the deadlines get more slack.
            self._link.io().raise_slack()
        self.cycles += 1

    def _may_chain(self, values: Tuple[int, ...], servos: List[Servo]) -> bool:
        """
        Return True when the next read may go on the wire before this block is taken.

        Nothing may wait to be written before it (goals, a task's steps, a pair's torque-off:
        none while a read is in flight), nobody may wait for the lock (a chained read keeps
        it), and the block must be taken without a transaction (every servo known, no motion
        part of all zeros, which Samples.take_one reads again to tell a restart). What the
        cycle's write also does (command timeouts, hardware-error recovery) still runs at every
        cycle that does not chain: every whole-block read (the health part, at least once a
        second), every cycle with a goal.
        """
        if (self._goals.waiting() or not self._ctx.tasks.idle or self._ctx.roster.secondary
                or self._lock.waiting):
            return False
        fields = BLOCK.TAGGED_FIELDS
        for index, servo in enumerate(servos):
            start = index * fields
            if servo.state is None or not (values[start] or values[start + 1]
                                           or values[start + 2]):
                return False
        return True


def _merge(result: SyncResult, ids: List[int], more: SyncResult) -> None:
    """Add a later read's answers to the cycle's, each dated by that read (sent, received)."""
    got = time.monotonic()
    result.data.update(more.data)
    result.alerts.update(more.alerts)
    result.dated.update({servo_id: (more.sent_s, got) for servo_id in ids})
    result.dated.update(more.dated)
    result.clean = result.clean and more.clean
