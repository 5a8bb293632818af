"""
Who the cycle reads and how: its reads by state-block layout, the Protocol 1.0 servos, fast or not.

Taken again after configure and whenever a task begins or ends (refresh): the servos read (a
servo with a task in progress is left out), grouped by where their state block lies and how
long it is (one sync read each, or one bulk read of all when they differ), the Protocol 1.0
servos apart, the servos whose usual clean block the bus decodes whole, and whether the reads
are fast (Fast Sync Read, or Fast Bulk Read). wire_plan says what one usual cycle puts on the
wire as they are grouped (the bus-limit report and the diagnostics); judge_fast is read_mode
auto's judgement of the fast reads. No transaction here: driver/cycle.Cycle reads by this plan.
"""

from typing import Dict, FrozenSet, List, Optional, Tuple

from dxl_servo_driver.bus import FRAMERS, READ_TAGS, SyncResult
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.servo import BLOCK, Servo, Throttle

# read_mode auto: this many Fast Sync Reads in a row with no part taken and it is given up.
FAST_EMPTY_LIMIT = 3
TAGGED = BLOCK.tagged_struct   # motion and tick are laid out alike on every model
TAGGED_FIELDS = TAGGED.format.lstrip('<')   # each servo's data in a whole-block decode
# A cycle's goal per servo as the bus limit counts it: a position (4 bytes; 2 on the Protocol
# 1.0 tables, whose goals are 2 bytes).
GOAL_BYTES = 4
# The tag a tickless block's read carries on average (the bus limit counts it).
_MEAN_TAG = (READ_TAGS - 1) // 2
GOAL_BYTES_1 = 2


class ReadPlan:
    """The servos the cycle reads, grouped as it reads them; whether its reads are fast."""

    def __init__(self, ctx: Context) -> None:
        self._ctx = ctx
        self._roster = ctx.roster
        self._tasks = ctx.tasks   # joints with a task in progress are left out of the read
        self._warn_throttled = Throttle(ctx.log.warn, clock=ctx.clock)
        self.ids: List[Tuple[Servo, int]] = []
        # Servos whose block is the X layout, read through indirect entries and tick-dated:
        # the usual cycle decodes them with one struct, the rest go the careful way.
        self.shaped: FrozenSet[int] = frozenset()
        self.block_servos: List[Servo] = []
        # The sync reads: (block, ids) per state-block layout; one on most buses.
        self.groups: List[Tuple[state_block.StateBlock, List[int]]] = []
        # The servos on Protocol 1.0, read after the sync reads.
        self.group_1: List[Servo] = []
        self.bulk_1 = False
        self.bulk_2 = False
        # Fast Sync Read: in use now; given up for good (read_mode auto) after fast reads in a
        # row that brought nothing back, counted in fast_empty.
        self.fast = False
        self.fast_given_up = False
        self.fast_empty = 0

    def refresh(self) -> None:
        """Take who is read again (after configure, or a task began or ended)."""
        # The hot path reads these instead of rebuilding lists every cycle. A servo with a task
        # in progress (being restored, rebooted, probed) is left out of the cycle's read.
        self.ids = [(servo, servo.servo_id) for servo in self._roster.active()
                    if servo.name not in self._tasks]
        self.shaped = frozenset(
            servo_id for servo, servo_id in self.ids
            if not servo.block.direct and servo.block.has_tick
            and servo.block.tagged_struct.format == TAGGED.format)
        groups: Dict[Tuple[int, int], Tuple[state_block.StateBlock, List[int]]] = {}
        # Servos whose protocol has no sync read (1.0) are read apart: by bulk read, or alone.
        synced = {servo.servo_id for servo, _ in self.ids
                  if FRAMERS[servo.joint.protocol].sync_read}
        self.group_1 = [servo for servo, servo_id in self.ids if servo_id not in synced]
        self.bulk_1 = all(servo.model.bulk_read for servo in self.group_1)
        for servo, servo_id in self.ids:
            if servo_id not in synced:
                continue
            block = servo.block
            groups.setdefault((block.read_address, block.size), (block, []))[1].append(servo_id)
        self.groups = sorted(groups.values(), key=lambda group: -len(group[1]))
        # Several layouts: one bulk read of all of them, each at its own address and length.
        self.bulk_2 = len(self.groups) > 1
        # One sync read of X-layout servos and nothing else: its usual clean block is decoded
        # whole by the bus (BlockTemplate), these servos in the order asked.
        self.block_servos = []
        if len(self.groups) == 1 and not self.group_1 and all(
                servo_id in self.shaped for servo_id in self.groups[0][1]):
            self.block_servos = [self._roster.by_id[servo_id] for servo_id in self.groups[0][1]]
        mode = self._ctx.config.read_mode
        self.fast = bool(self.groups) and (mode == 'fast_sync' or (
            mode == 'auto' and not self.fast_given_up
            and all(servo.model.has_fast_sync_read(servo.firmware_version)
                    for servo, servo_id in self.ids if servo_id in synced)))

    def wire_plan(self) -> List[state_block.Transaction]:
        """
        Return the transactions of one usual cycle as the servos are grouped now.

        Each sync read (one per block layout; fast when in use), the Protocol 1.0 servos' bulk
        read or reads (a tickless block counted with its mean tag), and one sync write of a goal
        per servo in each protocol: what the bus-limit report and the diagnostics count.
        """
        plan: List[state_block.Transaction] = []
        if self.bulk_2:
            lengths = [group_length(block, BLOCK.tagged_size, _MEAN_TAG)
                       for block, ids in self.groups for _ in ids]
            plan.append(state_block.Transaction(
                'fast bulk read' if self.fast else 'bulk read',
                (state_block.fast_bulk_read_bytes if self.fast else state_block.bulk_read_bytes)(
                    lengths), 1 if self.fast else len(lengths)))
        for block, ids in [] if self.bulk_2 else self.groups:
            length = group_length(block, BLOCK.tagged_size, _MEAN_TAG)
            if self.fast:
                plan.append(state_block.Transaction(
                    'fast sync read', state_block.fast_sync_read_bytes(len(ids), length), 1))
            else:
                plan.append(state_block.Transaction(
                    'sync read', state_block.sync_read_bytes(len(ids), length), len(ids)))
        lengths = [group_length(servo.block, BLOCK.tagged_size)
                   + (0 if servo.block.has_tick else _MEAN_TAG) for servo in self.group_1]
        if lengths and self.bulk_1:
            plan.append(state_block.Transaction(
                'bulk read (Protocol 1.0)', state_block.bulk_read_bytes_1(lengths), len(lengths)))
        else:
            plan.extend(state_block.Transaction('read (Protocol 1.0)',
                                                state_block.read_bytes_1(length), 1)
                        for length in lengths)
        on_2 = len(self.ids) - len(self.group_1)
        if on_2:
            plan.append(state_block.Transaction(
                'sync write', state_block.sync_write_bytes(on_2, GOAL_BYTES), 0))
        if self.group_1:
            plan.append(state_block.Transaction(
                'sync write (Protocol 1.0)',
                state_block.sync_write_bytes_1(len(self.group_1), GOAL_BYTES_1), 0))
        return plan

    def judge_fast(self, fast_parts: int, result: SyncResult) -> None:
        """
        read_mode auto: give Fast Sync Read up when it brings nothing back but servos answer.

        Silence alone proves nothing (servos off, cable out); a fast read with no part taken
        while the same servos then answered their one-off retries does: firmware or adapter
        that do not do Fast Sync Read.
        """
        if fast_parts:
            self.fast_empty = 0
            return
        if not result.dated:
            return
        self.fast_empty += 1
        if self._ctx.config.read_mode == 'auto' and self.fast_empty >= FAST_EMPTY_LIMIT:
            self.fast = False
            self.fast_given_up = True
            self._warn_throttled(
                'fast', f'read_mode auto: {FAST_EMPTY_LIMIT} fast sync reads in a row brought '
                'nothing back while the servos answered on their own; sync reads from now on '
                '(until the next configure)')


def linger(block: state_block.StateBlock) -> Optional[bool]:
    """
    Return read_dated's linger for a block: a ticked one never reads on (its tick dates it).

    One without a tick reads on to the deadline when the bus is suspicious (None): nothing else
    tells its answer from a late one.
    """
    return False if block.has_tick else None


def group_length(block: state_block.StateBlock, length: int, tag: int = 0) -> int:
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
