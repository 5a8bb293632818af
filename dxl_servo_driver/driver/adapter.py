"""
The USB adapter's latency timer: the one the file declares, checked against the real one.

An FTDI adapter holds what it receives until its latency timer runs out (Linux's default is
16 ms; our udev rule sets 1 ms) before the host sees a byte. Every reply deadline counts on that
timer, so a file saying 1 ms behind a 16 ms adapter made every answer come after its deadline
and the node refused to start, "servo did not answer": the most common Dynamixel set-up mistake.
So at configure, before any servo is pinged:

- where Linux says the adapter's timer (sysfs, a USB serial device), that value is used, with
  a warning when the file says another;
- elsewhere (a pty, an adapter without that file) a ping's answer is timed with a generous
  deadline, and if it came later than the file's timer allows, the timer it implies is used,
  with a warning that says how late the replies come and what to do.

Either way the node runs at the rate the adapter allows (the bus budget counts the timer in
force) rather than refusing to start.
"""

import math
from typing import List, Optional, Sequence, Tuple

from dxl_servo_driver.bus import Bus, DEADLINE_SLACK_S, MAX_DEADLINE_SLACK_S
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.servo import Servo
from dxl_servo_driver.serial_port import adapter_latency_timer_ms

# Pings timed (of the first servos that answer): the largest delay is taken, since an FTDI
# chip hands its buffer over anywhere from at once to a whole timer after the data came.
TIMED_PINGS = 5
# Servos tried for an answer before giving up on timing (a silent one costs a whole listen).
SERVOS_TRIED = 3
# What the host's wake-up and the servos' Return Delay Time (500 us from the factory) may add to
# an answer's delay before it says the adapter held it.
WAKE_ALLOWANCE_S = 0.5e-3
UDEV_HINT = ('install the udev rule (udev/99-dxl-servo-driver.rules: 1 ms on FTDI adapters) '
             'or set latency_timer: {ms:g}')


def settle_latency_timer(ctx: Context, servos: Sequence[Servo]) -> None:
    """Set the bus's latency timer to the adapter's real one, warning where the file differs."""
    bus = ctx.link.bus
    if bus is None:
        return
    declared_ms = ctx.config.latency_timer
    os_ms = adapter_latency_timer_ms(ctx.config.port)
    if os_ms is not None:
        if abs(os_ms - declared_ms) >= 0.5:
            bus.latency_timer_s = os_ms / 1000.0
            hint = UDEV_HINT.format(ms=os_ms) if os_ms > declared_ms else (
                f'set latency_timer: {os_ms:g}')
            ctx.log.warn(f'the adapter at {ctx.config.port} has a latency timer of {os_ms:g} ms '
                         f'(Linux says so) where latency_timer is {declared_ms:g} ms: using '
                         f'{os_ms:g} ms; {hint}')
        return
    timed = _time_replies(bus, servos)
    if timed is None:
        return
    servo, delays = timed
    delay_s = max(delays)
    allowed_s = bus.latency_timer_s + WAKE_ALLOWANCE_S + DEADLINE_SLACK_S / 2
    if delay_s <= allowed_s:
        return
    # The timer it implies, to the whole millisecond (timers are set in ms), never below the
    # file's.
    implied_ms = max(declared_ms, float(math.ceil((delay_s - WAKE_ALLOWANCE_S) * 1000.0)))
    bus.latency_timer_s = implied_ms / 1000.0
    # Answers that came this far apart will again: the deadlines' slack starts wide enough for
    # that spread (the bus narrows it again once nothing comes late for long).
    spread_s = delay_s - min(delays)
    bus.slack_s = min(MAX_DEADLINE_SLACK_S, max(bus.slack_s, DEADLINE_SLACK_S + spread_s))
    late_ms = delay_s * 1000.0 - declared_ms
    ctx.log.warn(f'replies arrive ~{late_ms:.0f} ms late (id {servo.servo_id} answered '
                 f'{delay_s * 1000.0:.1f} ms after its wire time, where latency_timer is '
                 f"{declared_ms:g} ms): the adapter's latency timer is probably "
                 f'{implied_ms:g} ms; {UDEV_HINT.format(ms=implied_ms)}. Running with '
                 f'{implied_ms:g} ms.')


def _time_replies(bus: Bus, servos: Sequence[Servo]) -> Optional[Tuple[Servo, List[float]]]:
    """Return the first servo that answers and its pings' delays; None if none does."""
    for servo in list(servos)[:SERVOS_TRIED]:
        delays: List[float] = []
        for _ in range(TIMED_PINGS):
            delay_s = bus.reply_delay(servo.servo_id)
            if delay_s is None:
                break
            delays.append(delay_s)
        if delays:
            return servo, delays
    return None
