"""
Terminal speeds at any rate, through Linux's termios2 ioctls (4.5 Mbps has no Bxxx constant).

Plain OS calls, no serial library: the serial transport sets its device's speed with them, and
virtual_bus and the test adapters set and read the speed of their pseudo-terminals.
"""

import array
import fcntl
import termios
from typing import Dict

# struct termios2 on the generic Linux ABI (x86, arm, arm64, riscv): four tcflag_t, c_line,
# c_cc[19], c_ispeed, c_ospeed = 44 bytes; the speeds are its 10th and 11th 32-bit words.
_TERMIOS2_WORDS = 11
_TERMIOS2_SIZE = 4 * _TERMIOS2_WORDS
_IOC_READ = 2
_IOC_WRITE = 1
TCGETS2 = (_IOC_READ << 30) | (_TERMIOS2_SIZE << 16) | (ord('T') << 8) | 0x2A
TCSETS2 = (_IOC_WRITE << 30) | (_TERMIOS2_SIZE << 16) | (ord('T') << 8) | 0x2B
BOTHER = 0o010000
_CFLAG_WORD = 2
_ISPEED_WORD = 9
_OSPEED_WORD = 10


def _standard_speeds() -> Dict[int, int]:
    """Termios Bxxx constant -> bps, for the fallback when TCGETS2 is unavailable."""
    speeds: Dict[int, int] = {}
    for name in dir(termios):
        if name.startswith('B') and name[1:].isdigit():
            speeds[getattr(termios, name)] = int(name[1:])
    return speeds


_SPEEDS = _standard_speeds()


def tty_speed_bps(fd: int) -> int:
    """Return the output speed of a terminal in bps, custom (BOTHER) speeds included."""
    buf = array.array('I', [0] * _TERMIOS2_WORDS)
    try:
        fcntl.ioctl(fd, TCGETS2, buf, True)
        if buf[_OSPEED_WORD] > 0:
            return int(buf[_OSPEED_WORD])
    except OSError:
        pass
    return _SPEEDS.get(termios.tcgetattr(fd)[5], 0)


def set_tty_speed(fd: int, baud_bps: int) -> bool:
    """Set a terminal's speeds to baud_bps through termios2 (any rate); False if refused."""
    buf = array.array('I', [0] * _TERMIOS2_WORDS)
    try:
        fcntl.ioctl(fd, TCGETS2, buf, True)
        buf[_CFLAG_WORD] = (buf[_CFLAG_WORD] & ~termios.CBAUD) | BOTHER
        buf[_ISPEED_WORD] = baud_bps
        buf[_OSPEED_WORD] = baud_bps
        fcntl.ioctl(fd, TCSETS2, buf)
    except OSError:
        return False
    return True
