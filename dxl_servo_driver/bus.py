"""
The bus: the transactions of one port of Dynamixel servos (Protocol 2.0 or 1.0), in three layers.

The rest of the package imports the bus from here: Bus, and every name below (`__all__`). The
work is done in three modules, each layer built on the one below it (as pymodbus has them):

- wire.py (Wire): the port, the lock, the framer in force, the flush, the deadlines and their
  adaptive slack, the local echo, the learned turnaround, the dirty flag, the counters, and the
  one frame classifier (Request) and collector every transaction reads its replies with.
- transactions.py (Transactions): the one-off transactions (ping, read, write, reboot, CLEAR,
  factory reset, sync write, reply_delay, ping_sweep, broadcast_ping); they reach the wire
  through _send, _read, _collect, reply_timeout_s and mark_dirty.
- group_reads.py (GroupReads): sync and bulk reads and their fast forms, begun and collected
  apart (SyncRead) so a cycle can do other work while the servos answer; the usual clean block
  is checked and decoded whole (BlockTemplate).

What differs between Protocol 2.0 and 1.0 is the framer's to say (protocol.Framer; PROTOCOL_2
and protocol1.PROTOCOL_1), never a branch on its version in these layers.

Until the split this module held all three layers: some 1,450 lines, one class of ~900 (its
docstring said ~800 lines, on purpose, for the shared state; that state is now the wire's, and
the layers above reach it through the few methods named above). What is left here is the facade.
A setting is changed where its layer reads it (a test patches wire.SLACK_DECAY_REQUESTS, not the
name re-exported here).
"""

from dxl_servo_driver.group_reads import BlockTemplate, GroupReads, SyncRead, SyncResult
from dxl_servo_driver.protocol import ERROR_TEXT
from dxl_servo_driver.protocol1 import MODEL_NUMBER_ADDRESS as MODEL_NUMBER_ADDRESS_1
from dxl_servo_driver.transactions import (
    BROADCAST_PING_PER_ID_S, broadcast_ping_s, CONFIRM_ATTEMPTS, LATENCY_LISTEN_S, Method,
    PING_REPLY_PARAMS, READ_TAGS, Sweep, SWEEP_MARGIN_S, sweep_spacing_s)
from dxl_servo_driver.wire import (
    ANSWER, Collected, CORRUPT, Counters, DEADLINE_SLACK_S, DIRTY_HOLD_S, ECHO,
    ECHO_MISSES_TO_FORGET, FRAMERS, MAX_DEADLINE_SLACK_S, MIN_SLEEP_S, RECENT_PACKETS, Request,
    SLACK_DECAY_REQUESTS, STRAY, TURNAROUND_ON_TIME, TURNAROUND_STEP_S)

__all__ = [
    'ANSWER', 'BlockTemplate', 'broadcast_ping_s', 'BROADCAST_PING_PER_ID_S', 'Bus', 'Collected',
    'CONFIRM_ATTEMPTS', 'CORRUPT', 'Counters', 'DEADLINE_SLACK_S', 'DIRTY_HOLD_S', 'ECHO',
    'ECHO_MISSES_TO_FORGET', 'ERROR_TEXT', 'FRAMERS', 'LATENCY_LISTEN_S', 'MAX_DEADLINE_SLACK_S',
    'Method', 'MIN_SLEEP_S', 'MODEL_NUMBER_ADDRESS_1', 'PING_REPLY_PARAMS', 'READ_TAGS',
    'RECENT_PACKETS', 'Request', 'SLACK_DECAY_REQUESTS', 'STRAY', 'Sweep', 'sweep_spacing_s',
    'SWEEP_MARGIN_S', 'SyncRead', 'SyncResult', 'TURNAROUND_ON_TIME', 'TURNAROUND_STEP_S',
]


class Bus(GroupReads):
    """
    One bus of servos on one port. Thread-safe: one transaction at a time.

    A bus may carry both protocols: the one given is its default (broadcasts, and every id not
    told otherwise); speak() says an id answers in the other. The framer in force (`framer`)
    is switched only under the bus lock, for one transaction.

    The bus never retries on its own; the caller decides what a failure means.

    It is the group reads over the transactions over the wire, by inheritance (GroupReads,
    Transactions, Wire) rather than three objects: one per port holds the state all of them
    share, and every caller's `Bus(...)`, attributes and methods stay as they were.
    """
