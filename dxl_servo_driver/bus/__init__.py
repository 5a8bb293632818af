"""
The bus: the transactions of one port of Dynamixel servos (Protocol 2.0 or 1.0), in three layers.

The face of the bus layer: the rest of the package imports the bus from here, and only the
names below (`__all__`). The work is done in three modules, each a class that holds the one below
as an object and uses its public names only (its class docstring lists them); Bus holds them
all and is what every caller uses:

- wire.py (Wire): the port, the lock, the framer in force, the flush, the deadlines and their
  adaptive slack, the local echo, the learned turnaround, the dirty flag, the counters, and the
  one frame classifier (Request) and collector every transaction reads its replies with.
- transactions.py (Transactions, over the wire): the one-off transactions (ping, read, write,
  reboot, CLEAR, factory reset, sync write, reply_delay, ping_sweep, broadcast_ping).
- group_reads.py (GroupReads, over the wire): sync and bulk reads and their fast forms, begun
  and collected apart (SyncRead) so a cycle can do other work while the servos answer; the
  usual clean block is checked and decoded whole (BlockTemplate).

What differs between Protocol 2.0 and 1.0 is the framer's to say (protocol.Framer; PROTOCOL_2
and protocol1.PROTOCOL_1), never a branch on its version in these layers. A setting is changed
where its layer reads it (a test patches wire.SLACK_DECAY_REQUESTS, not a name here).
"""

from typing import Optional

from dxl_servo_driver.bus.discovery import (
    all_bauds, default_bauds, DEFAULT_PROTOCOL, find_one_servo, FoundServo,
    LINUX_LATENCY_TIMER_MS, MAX_RETURN_DELAY_S, NO_SERVO_HINT, NoServo, NotOneServo, OneServo,
    plan, protocol_1_bauds, scan_bus, ScanResult, set_baud, Step, sweep_wait_s)
from dxl_servo_driver.bus.group_reads import GroupReads, SyncRead, SyncResult
from dxl_servo_driver.bus.transactions import READ_TAGS, Transactions
from dxl_servo_driver.bus.wire import (
    BusTrace, DEADLINE_SLACK_S, MAX_DEADLINE_SLACK_S, Wire)
from dxl_servo_driver.port import RawPort
from dxl_servo_driver.protocol import Framer, FRAMERS, PROTOCOL_2

__all__ = [
    'Bus', 'BusTrace', 'DEADLINE_SLACK_S', 'FRAMERS', 'MAX_DEADLINE_SLACK_S', 'READ_TAGS',
    'SyncRead', 'SyncResult',
    # the search of a bus (discovery.py)
    'all_bauds', 'default_bauds', 'DEFAULT_PROTOCOL', 'find_one_servo', 'FoundServo',
    'LINUX_LATENCY_TIMER_MS', 'MAX_RETURN_DELAY_S', 'NO_SERVO_HINT', 'NoServo', 'NotOneServo',
    'OneServo', 'plan', 'protocol_1_bauds', 'scan_bus', 'ScanResult', 'set_baud', 'Step',
    'sweep_wait_s',
]


class Bus:
    """
    One bus of servos on one port. Thread-safe: one transaction at a time.

    A bus may carry both protocols: the one given is its default (broadcasts, and every id not
    told otherwise); speak() says an id answers in the other. The framer in force (`framer`)
    is switched only under the bus lock, for one transaction.

    The bus never retries on its own; the caller decides what a failure means.

    What it offers is its layers' public names, each the layer's own method (bound here, so a
    call costs no more than on the layer itself) or attribute:

    - the wire's (wire.Wire): speak, framer_for, speaking, byte_time_s, reply_timeout_s,
      raise_slack, mark_dirty, alert, set_baud, trace_to, attach, close; `lock`, `counters`,
      and as properties `port`, `trace`, `framer`, `default_framer`, `echo`, `dirty`,
      `baud_bps`, and the timing a caller sets: `latency_timer_s`, `return_delay_s`,
      `least_return_delay_s`, `turnaround_s`, `slack_s`.
    - the one-off transactions' (transactions.Transactions): transact, ping, reply_delay,
      ping_sweep, broadcast_ping, broadcast_sweep, read, read_fresh, read_dated, write,
      read_item, write_item, reboot, clear_multi_turn, factory_reset, sync_write.
    - the group reads' (group_reads.GroupReads): sync_read, begin_sync_read, bulk_read,
      begin_bulk_read.
    """

    def __init__(self, port: RawPort, baud_bps: int, latency_timer_s: float = 0.016,
                 return_delay_s: float = 0.0005, framer: Framer = PROTOCOL_2) -> None:
        wire = Wire(port, baud_bps, latency_timer_s, return_delay_s, framer)
        transactions = Transactions(wire)
        reads = GroupReads(wire)
        self._wire = wire
        # The same objects as the wire's, for as long as the bus lives.
        self.lock = wire.lock
        self.counters = wire.counters
        # The wire's.
        self.speak = wire.speak
        self.framer_for = wire.framer_for
        self.speaking = wire.speaking
        self.byte_time_s = wire.byte_time_s
        self.reply_timeout_s = wire.reply_timeout_s
        self.raise_slack = wire.raise_slack
        self.mark_dirty = wire.mark_dirty
        self.alert = wire.alert
        self.set_baud = wire.set_baud
        self.trace_to = wire.trace_to
        self.attach = wire.attach
        self.close = wire.close
        # The one-off transactions'.
        self.transact = transactions.transact
        self.ping = transactions.ping
        self.reply_delay = transactions.reply_delay
        self.ping_sweep = transactions.ping_sweep
        self.broadcast_ping = transactions.broadcast_ping
        self.broadcast_sweep = transactions.broadcast_sweep
        self.read = transactions.read
        self.read_fresh = transactions.read_fresh
        self.read_dated = transactions.read_dated
        self.write = transactions.write
        self.read_item = transactions.read_item
        self.write_item = transactions.write_item
        self.reboot = transactions.reboot
        self.clear_multi_turn = transactions.clear_multi_turn
        self.factory_reset = transactions.factory_reset
        self.sync_write = transactions.sync_write
        # The group reads'.
        self.sync_read = reads.sync_read
        self.begin_sync_read = reads.begin_sync_read
        self.bulk_read = reads.bulk_read
        self.begin_bulk_read = reads.begin_bulk_read

    # the wire's state ----------------------------------------------------------------------
    @property
    def port(self) -> RawPort:
        """Return the port the bus is on (a wire.TracedPort around it while traced)."""
        return self._wire.port

    @property
    def trace(self) -> Optional[BusTrace]:
        """Return the trace every byte of the port is written to (None: not traced)."""
        return self._wire.trace

    @property
    def framer(self) -> Framer:
        """Return the framer in force (the default but during a transaction in another)."""
        return self._wire.framer

    @property
    def default_framer(self) -> Framer:
        """Return the framer of broadcasts and of every id not told otherwise (speak)."""
        return self._wire.default_framer

    @property
    def echo(self) -> bool:
        """Return True once the adapter was found to echo what is sent (learned)."""
        return self._wire.echo

    @property
    def dirty(self) -> bool:
        """Return True while the bus is suspicious (an anomaly happened lately)."""
        return self._wire.dirty

    @property
    def baud_bps(self) -> int:
        """Return the line speed (set_baud changes it)."""
        return self._wire.baud_bps

    @property
    def latency_timer_s(self) -> float:
        """Return the USB adapter's latency timer every deadline counts."""
        return self._wire.latency_timer_s

    @latency_timer_s.setter
    def latency_timer_s(self, value: float) -> None:
        self._wire.latency_timer_s = value

    @property
    def return_delay_s(self) -> float:
        """Return the largest Return Delay Time expected on this bus."""
        return self._wire.return_delay_s

    @return_delay_s.setter
    def return_delay_s(self, value: float) -> None:
        self._wire.return_delay_s = value

    @property
    def least_return_delay_s(self) -> float:
        """Return the smallest Return Delay Time on this bus (no answer comes sooner)."""
        return self._wire.least_return_delay_s

    @least_return_delay_s.setter
    def least_return_delay_s(self, value: float) -> None:
        self._wire.least_return_delay_s = value

    @property
    def turnaround_s(self) -> float:
        """Return how long after its wire time a sync read's block is whole (learned)."""
        return self._wire.turnaround_s

    @turnaround_s.setter
    def turnaround_s(self, value: float) -> None:
        self._wire.turnaround_s = value

    @property
    def slack_s(self) -> float:
        """Return the deadline slack in force (wire.DEADLINE_SLACK_S)."""
        return self._wire.slack_s

    @slack_s.setter
    def slack_s(self, value: float) -> None:
        self._wire.slack_s = value
