"""
Dating a servo's samples by its Realtime Tick: a reply older than its request is refused.

Pure arithmetic, per servo: the driver keeps one TickClock in each servo's record.
"""

from typing import Optional

from dxl_servo_driver.models.xm430 import TICK_PERIOD_MS


class TickClock:
    """
    Date a servo's samples by its Realtime Tick and refuse those older than their request.

    A status packet carries no sequence number, so a late reply of an earlier identical request
    looks like the answer to this one. The servo's tick does tell when the sample was taken.
    Tick and host clock differ by an unknown offset c = tick - t_host (ms). A reply to a request
    sent at s and received at r was sampled at some t in [s, r], so tick - r <= c: the largest
    (tick - r) seen is a lower bound of c (a late reply only lowers tick - r, so it can never
    raise the bound). A sample whose tick is below s + bound by more than tolerance_ms was taken
    before its request went out: it answers an earlier request. The bound is relaxed by
    drift_ppm between samples, for the two clocks' crystals.

    What this can promise: a sample passed was taken no more than tolerance_ms before its
    request, plus the bound's own error, c - bound = the quickest any reply came back after its
    sample (wire, the adapter's latency at its shortest) and the tick's 1 ms resolution. A late
    copy of a reply one cycle old is refused as long as the cycle is longer than that.

    The offset holds only while the servo runs on: whoever stops watching a servo (cleanup,
    deactivate, a lost port) must reset() it, since the servo may have restarted meanwhile (or,
    the simulator, be a new one), its tick from 0. A bound no sample confirmed for forget_after_s
    is forgotten too: relaxed by drift it would soon mean nothing, and past half the tick's wrap
    it would mean the opposite.
    """

    def __init__(self, tolerance_ms: float = 2.0, drift_ppm: float = 300.0,
                 forget_after_s: float = 60.0) -> None:
        self.tolerance_ms = tolerance_ms
        self.drift = drift_ppm * 1e-6
        self.forget_after_ms = forget_after_s * 1000.0
        self._bound_ms: Optional[float] = None
        self._bound_at_ms = 0.0
        self.refused = 0

    def reset(self) -> None:
        """Forget the offset (the servo restarted: its tick started again from 0)."""
        self._bound_ms = None

    def check(self, tick: int, sent_s: float, received_s: float) -> bool:
        """Return False when the sample was taken before sent_s; learn from it otherwise."""
        # Run for every servo every cycle: each difference is folded into [-P/2, P/2) in place,
        # (x + P/2) % P - P/2, rather than by a call.
        period = TICK_PERIOD_MS
        half = period / 2
        received_ms = received_s * 1000.0
        bound = self._bound_ms
        if bound is None or received_ms - self._bound_at_ms > self.forget_after_ms:
            self._bound_ms = (tick - received_ms + half) % period - half
            self._bound_at_ms = received_ms
            return True
        elapsed = received_ms - self._bound_at_ms
        if elapsed > 0.0:
            bound -= self.drift * elapsed
        if (bound - (tick - sent_s * 1000.0) + half) % period - half > self.tolerance_ms:
            self.refused += 1
            return False
        rise = (tick - received_ms - bound + half) % period - half
        if rise > 0.0:
            bound += rise
        self._bound_ms = (bound + half) % period - half
        self._bound_at_ms = received_ms
        return True
