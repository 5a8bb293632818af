"""
Replies that overlap on the wire: what the host's UART reads when two servos answer at once.

On a real bus every servo answering a request drives the RS-485 line; two answering the same
request (the same id, twice: the factory state, every new servo being id 1) drive it at the
same time and fight. The model, the simplest that stays deterministic:

* The line is the AND of what the transmitters send, idle being 1: a driven 0 wins. (Two
  push-pull drivers fighting leave a differential voltage near zero, which a receiver may read
  either way; reading it as the 0 of the start bits makes every overlap visible.)
* Each byte is a UART frame of 10 bits: a start bit (0), 8 data bits, least significant first,
  a stop bit (1).
* No two servos start in the same bit: their firmware does not answer within the same few
  microseconds. The servo given k-th to the bus (0-based) starts SKEW_BITS * k bit times after
  its Return Delay Time; the skew of one bit is enough to garble every byte that overlaps.
* The host's UART waits for a start bit (a 1 -> 0 edge, or a 0 right after a frame), samples
  the 8 data bits at their centres and skips the stop bit; a stop bit read as 0 (a framing
  error) still delivers the byte, as Linux does in raw mode (no INPCK).

So a host never sees a clean reply from one of several servos whose answers overlap: from
the first byte where a second one starts, it reads bytes that are neither's, and the packet's
header or CRC fails. Answers that do not overlap (Return Delay Times further apart than a
reply lasts) reach it one after the other, as they would on a real line.
"""

from typing import Sequence

BITS_PER_FRAME = 10   # start, 8 data, stop
SKEW_BITS = 1


def frame_bits(data: bytes) -> list[int]:
    """Return the line levels of bytes sent by one UART, one entry per bit time."""
    bits: list[int] = []
    for byte in data:
        bits.append(0)
        bits.extend((byte >> k) & 1 for k in range(8))
        bits.append(1)
    return bits


def uart_read(line: Sequence[int]) -> bytes:
    """Return the bytes a UART reads from line levels sampled once per bit time."""
    out = bytearray()
    size = len(line)
    position = 0
    while position < size:
        if line[position]:
            position += 1   # idle, or a stop bit: wait for a start bit
            continue
        value = 0
        for k in range(8):
            at = position + 1 + k
            if at >= size or line[at]:
                value |= 1 << k   # past the end the line is idle: 1
        out.append(value)
        position += BITS_PER_FRAME
    return bytes(out)


def wired_and(streams: Sequence[tuple[int, bytes]]) -> bytes:
    """
    Return what the host reads when several transmitters send at once.

    streams holds (the bit time the transmitter starts at, its bytes); the result is read from
    the earliest start on.
    """
    if not streams:
        return b''
    first = min(start for start, _ in streams)
    end = max(start + BITS_PER_FRAME * len(data) for start, data in streams)
    line = [1] * (end - first)
    for start, data in streams:
        offset = start - first
        for k, bit in enumerate(frame_bits(data)):
            if not bit:
                line[offset + k] = 0
    return uart_read(line)
