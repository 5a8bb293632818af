"""
The bus: the transactions of one port of Dynamixel servos (Protocol 2.0 or 1.0), in three layers.

The face of the bus layer: the rest of the package imports the bus from here, and only the
names below (`__all__`). The work is done in three modules, each layer built on the one below:

- wire.py (Wire): the port, the lock, the framer in force, the flush, the deadlines and their
  adaptive slack, the local echo, the learned turnaround, the dirty flag, the counters, and the
  one frame classifier (Request) and collector every transaction reads its replies with.
- transactions.py (Transactions): the one-off transactions (ping, read, write, reboot, CLEAR,
  factory reset, sync write, reply_delay, ping_sweep, broadcast_ping).
- group_reads.py (GroupReads): sync and bulk reads and their fast forms, begun and collected
  apart (SyncRead) so a cycle can do other work while the servos answer; the usual clean block
  is checked and decoded whole (BlockTemplate).

What differs between Protocol 2.0 and 1.0 is the framer's to say (protocol.Framer; PROTOCOL_2
and protocol1.PROTOCOL_1), never a branch on its version in these layers. A setting is changed
where its layer reads it (a test patches wire.SLACK_DECAY_REQUESTS, not a name here).
"""

from dxl_servo_driver.bus.discovery import (
    all_bauds, default_bauds, DEFAULT_PROTOCOL, find_one_servo, FoundServo,
    LINUX_LATENCY_TIMER_MS, MAX_RETURN_DELAY_S, NO_SERVO_HINT, NoServo, NotOneServo, OneServo,
    plan, protocol_1_bauds, scan_bus, ScanResult, set_baud, Step, sweep_wait_s)
from dxl_servo_driver.bus.group_reads import GroupReads, SyncRead, SyncResult
from dxl_servo_driver.bus.transactions import READ_TAGS
from dxl_servo_driver.bus.wire import BusTrace, DEADLINE_SLACK_S, FRAMERS, MAX_DEADLINE_SLACK_S

__all__ = [
    'Bus', 'BusTrace', 'DEADLINE_SLACK_S', 'FRAMERS', 'MAX_DEADLINE_SLACK_S', 'READ_TAGS',
    'SyncRead', 'SyncResult',
    # the search of a bus (discovery.py)
    'all_bauds', 'default_bauds', 'DEFAULT_PROTOCOL', 'find_one_servo', 'FoundServo',
    'LINUX_LATENCY_TIMER_MS', 'MAX_RETURN_DELAY_S', 'NO_SERVO_HINT', 'NoServo', 'NotOneServo',
    'OneServo', 'plan', 'protocol_1_bauds', 'scan_bus', 'ScanResult', 'set_baud', 'Step',
    'sweep_wait_s',
]


class Bus(GroupReads):
    """
    One bus of servos on one port. Thread-safe: one transaction at a time.

    A bus may carry both protocols: the one given is its default (broadcasts, and every id not
    told otherwise); speak() says an id answers in the other. The framer in force (`framer`)
    is switched only under the bus lock, for one transaction.

    The bus never retries on its own; the caller decides what a failure means.
    """
