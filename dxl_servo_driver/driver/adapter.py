"""
The USB adapter's latency timer: the one the file declares, checked against the real one.

An FTDI adapter holds what it receives until its latency timer runs out (Linux's default is
16 ms; our udev rule sets 1 ms) before the host sees a byte. Every reply deadline counts on that
timer, so a file saying 1 ms behind a 16 ms adapter puts every answer after its deadline and
a node that trusted the file would not start, "servo did not answer": the most common Dynamixel
set-up mistake.
So at configure, before any servo is pinged, the adapter's real timer is measured
(`measure_latency_timer`, which `scan` uses too for the file it writes):

- where Linux says the adapter's timer (sysfs, a USB serial device), that value is used, with
  a warning when the file says another;
- elsewhere (a pty, an adapter without that file) a ping's answer is timed with a generous
  deadline. If it came later than the file's timer allows, the timer it implies is used, with a
  warning that says how late the replies come and what to do. If it came well before (a pty
  answers at once, where a file says Linux's 16 ms), the bus limit counts the timer measured,
  said at info level; the reply deadlines keep the file's longer one (a timing taken at
  configure is a sample: a loaded machine may answer later, and a longer deadline costs only
  when a reply is lost).

Either way the node runs at the rate the adapter allows (the bus budget counts the timer
found: `Link.adapter_latency_s`) rather than refusing to start, or warning that the bus cannot
carry a rate it then reaches.
"""

from dataclasses import dataclass
import math
from typing import List, Optional, Sequence, Tuple

from dxl_servo_driver.bus import Bus, DEADLINE_SLACK_S, MAX_DEADLINE_SLACK_S
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.servo import Servo
from dxl_servo_driver.port import adapter_latency_timer_ms

# Pings timed (of the first servo that answers). The largest delays count, since an FTDI chip
# hands its buffer over anywhere from at once to a whole timer after the data came; but not the
# very largest alone: one answer held up by the host (a loaded machine that ran neither end of a
# pty for 14 ms, seen) says nothing of the adapter. So the second largest of these says the
# timer; once it says the file's is too short, the largest sets the deadlines (generous costs
# nothing while replies come).
TIMED_PINGS = 10
# Servos tried for an answer before giving up on timing (a silent one costs a whole listen).
SERVOS_TRIED = 3
# What the host's wake-up and the servos' Return Delay Time (500 us from the factory) may add to
# an answer's delay before it says the adapter held it.
WAKE_ALLOWANCE_S = 0.5e-3
# The least a measured timer counts as: adapters' timers are set in whole ms from 1 (an FTDI
# chip's least), and a pty's answer comes through another process's wake-up.
MIN_TIMER_MS = 1.0
UDEV_HINT = ('install the udev rule (udev/99-dxl-servo-driver.rules: 1 ms on FTDI adapters) '
             'or set latency_timer: {ms:g}')
LINUX = 'linux'
TIMED = 'timed'


@dataclass(frozen=True)
class Measured:
    """An adapter's latency timer as found: Linux's word for it, or a ping's answer timed."""

    timer_ms: float           # whole ms, at least MIN_TIMER_MS where timed
    how: str                  # LINUX or TIMED
    servo_id: Optional[int] = None   # timed: whose answers
    delay_s: float = 0.0      # timed: the delay after its wire time all answers but one kept
    spread_s: float = 0.0     # timed: the largest delay less the least one
    largest_s: float = 0.0    # timed: the largest delay

    def describe(self) -> str:
        """Return where the value comes from, in a few words (a parameter file's comment)."""
        if self.how == LINUX:
            return 'read from the adapter'
        return (f'measured: id {self.servo_id} answered within {self.delay_s * 1000.0:.1f} ms '
                'of its wire time (pings timed)')


def implied_timer_ms(delay_s: float) -> float:
    """Return the latency timer an answer this late implies, to the whole ms (timers are)."""
    return max(MIN_TIMER_MS, float(math.ceil(round((delay_s - WAKE_ALLOWANCE_S) * 1000.0, 6))))


def measure_latency_timer(port: str, bus: Bus, servo_ids: Sequence[int]) -> Optional[Measured]:
    """
    Return the adapter's latency timer: Linux's (sysfs), else pings of servo_ids timed.

    None where neither says: no sysfs file and none of the first SERVOS_TRIED ids answers.
    Each id is pinged in the protocol the bus says it speaks (`Bus.speak`).
    """
    os_ms = adapter_latency_timer_ms(port)
    if os_ms is not None:
        return Measured(os_ms, LINUX)
    timed = _time_replies(bus, servo_ids)
    if timed is None:
        return None
    servo_id, delays = timed
    delays.sort()
    delay_s = delays[-2] if len(delays) > 1 else delays[-1]
    return Measured(implied_timer_ms(delay_s), TIMED, servo_id, delay_s,
                    delays[-1] - delays[0], delays[-1])


def settle_latency_timer(ctx: Context, servos: Sequence[Servo]) -> None:
    """Set the bus's latency timer to the adapter's real one, warning where the file differs."""
    bus = ctx.link.bus
    ctx.link.adapter_latency_s = None
    if bus is None:
        return
    declared_ms = ctx.config.latency_timer
    measured = measure_latency_timer(ctx.config.port, bus, [s.servo_id for s in servos])
    if measured is None:
        return
    if measured.how == LINUX:
        os_ms = measured.timer_ms
        ctx.link.adapter_latency_s = os_ms / 1000.0
        if abs(os_ms - declared_ms) >= 0.5:
            bus.latency_timer_s = os_ms / 1000.0
            hint = UDEV_HINT.format(ms=os_ms) if os_ms > declared_ms else (
                f'set latency_timer: {os_ms:g}')
            ctx.log.warn(f'the adapter at {ctx.config.port} has a latency timer of {os_ms:g} ms '
                         f'(Linux says so) where latency_timer is {declared_ms:g} ms: using '
                         f'{os_ms:g} ms; {hint}')
        return
    delay_s = measured.delay_s
    allowed_s = bus.latency_timer_s + WAKE_ALLOWANCE_S + DEADLINE_SLACK_S / 2
    if delay_s <= allowed_s:
        if declared_ms - measured.timer_ms >= 1.0:
            ctx.link.adapter_latency_s = measured.timer_ms / 1000.0
            ctx.log.info(
                f'id {measured.servo_id} answered within {delay_s * 1000.0:.1f} ms of its wire '
                f'time, where latency_timer is {declared_ms:g} ms: the bus limit counts '
                f"{measured.timer_ms:g} ms (the adapter's, as measured), replies are still "
                f'waited for up to {declared_ms:g} ms; set latency_timer: '
                f'{measured.timer_ms:g}')
        else:
            ctx.link.adapter_latency_s = bus.latency_timer_s
        return
    # From the largest delay, never below the file's.
    implied_ms = max(declared_ms, implied_timer_ms(measured.largest_s))
    bus.latency_timer_s = implied_ms / 1000.0
    ctx.link.adapter_latency_s = bus.latency_timer_s
    # Answers that came this far apart will again: the deadlines' slack starts wide enough for
    # that spread (the bus narrows it again once nothing comes late for long).
    bus.slack_s = min(MAX_DEADLINE_SLACK_S, max(bus.slack_s, DEADLINE_SLACK_S + measured.spread_s))
    largest_ms = measured.largest_s * 1000.0
    ctx.log.warn(f'replies arrive ~{largest_ms - declared_ms:.0f} ms late (id '
                 f'{measured.servo_id} answered {largest_ms:.1f} ms after its wire time, where '
                 f"latency_timer is {declared_ms:g} ms): the adapter's latency timer is "
                 f'probably {implied_ms:g} ms; {UDEV_HINT.format(ms=implied_ms)}. Running with '
                 f'{implied_ms:g} ms.')


def _time_replies(bus: Bus, servo_ids: Sequence[int]) -> Optional[Tuple[int, List[float]]]:
    """Return the first id that answers and its pings' delays; None if none does."""
    for servo_id in list(servo_ids)[:SERVOS_TRIED]:
        delays: List[float] = []
        for _ in range(TIMED_PINGS):
            delay_s = bus.reply_delay(servo_id)
            if delay_s is None:
                break
            delays.append(delay_s)
        if delays:
            return servo_id, delays
    return None
