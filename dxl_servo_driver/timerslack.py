"""
A thread's timer slack: how late Linux may end its sleeps and timed waits.

A thread's default slack is 50 us: a sleep until a reply is due ends up to 50-80 us after it,
and at the bus's pace that is a tenth of a cycle spent asleep with the answers there. With the
slack at 1 ns such a sleep ends about 10 us late. The cost is a timer of its own for each
sleep, nothing a thread that wakes a few times a cycle notices. Linux only (prctl); elsewhere
the slack stays as it is.
"""

_PR_SET_TIMERSLACK = 29


def fine_timer_slack() -> bool:
    """Ask Linux to end the calling thread's sleeps on time; return whether it did."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False
