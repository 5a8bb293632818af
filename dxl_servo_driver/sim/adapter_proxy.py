"""
A faulty adapter as a pseudo-terminal in front of a serial device (fault_engine.FaultEngine).

For clients that open a device path: the far end is typically a virtual_bus pty.
"""

import errno
import os
import select
import termios
import threading
import time
import tty
from typing import Optional

from dxl_servo_driver.port import set_tty_speed, tty_speed_bps
from dxl_servo_driver.sim.fault_engine import FaultControls, FaultEngine, Faults

READ_CHUNK = 4096
IDLE_S = 0.5            # the proxy thread's longest sleep (a wake pipe ends it early)
WRITE_TIMEOUT_S = 1.0   # how long the proxy waits for a full upstream device to take bytes


def _close_fd(fd: int) -> None:
    if fd >= 0:
        try:
            os.close(fd)
        except OSError:
            pass


def _set_raw(fd: int) -> None:
    """Put a terminal in raw mode (tty.setraw), keeping its speed, custom rates included."""
    baud_bps = tty_speed_bps(fd)
    try:
        tty.setraw(fd)
    except termios.error:  # a C library may refuse to write back a termios2 (BOTHER) speed
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = termios.B38400
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        tty.setraw(fd)
    if baud_bps:
        set_tty_speed(fd, baud_bps)


class AdapterProxy(FaultControls):
    """
    A faulty adapter as a pseudo-terminal in front of a serial device.

    The client opens `path`; its bytes go to the upstream device unchanged (echoed back when
    echo is on) and the servos' bytes come back through the engine. The baud rate the client
    sets on the pty is set on the upstream device before the bytes that follow are forwarded,
    since virtual_bus's servos only hear bytes at their own baud. One thread, sleeping in
    poll(), moves the bytes both ways and releases what the engine has scheduled on time.
    """

    def __init__(self, upstream_device: str, faults: Optional[Faults] = None,
                 seed: Optional[int] = 0, protocol: int = 2) -> None:
        self.upstream_device = upstream_device
        self.engine = FaultEngine(faults, seed, protocol=protocol)
        self.error: Optional[BaseException] = None  # what ended the thread early, if anything
        self.upstream_lost = False                  # the upstream device hung up
        self._path = ''
        self._master = self._slave = self._upstream = self._wake_r = self._wake_w = -1
        self._baud_bps = 0
        self._thread: Optional[threading.Thread] = None
        self._stopping = False
        self._lifecycle = threading.Lock()

    @property
    def path(self) -> str:
        """Return the pty slave's path for the client ('' before start())."""
        return self._path

    @property
    def upstream_baud(self) -> int:
        """Return the upstream device's current speed in bps."""
        return tty_speed_bps(self._upstream)

    def start(self) -> str:
        """Open the pty and the upstream device, start the thread; return the pty's path."""
        with self._lifecycle:
            if self._thread is not None or self._stopping:
                raise RuntimeError('an AdapterProxy starts once')
            try:
                self._wake_r, self._wake_w = os.pipe()
                os.set_blocking(self._wake_r, False)
                os.set_blocking(self._wake_w, False)
                self._upstream = os.open(self.upstream_device,
                                         os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                self._baud_bps = tty_speed_bps(self._upstream)
                _set_raw(self._upstream)
                self._master, self._slave = os.openpty()
                # Raw: no echo of what the client writes, no CR/LF or flow-control mangling.
                _set_raw(self._slave)
                # The client starts at the servos' speed unless it sets its own.
                set_tty_speed(self._slave, self._baud_bps)
                os.set_blocking(self._master, False)
                self._path = os.ttyname(self._slave)
                self.engine.add_listener(self._wake)
                self._thread = threading.Thread(target=self._run, name='adapter-proxy',
                                                daemon=True)
                self._thread.start()
            except BaseException:
                self.engine.remove_listener(self._wake)
                self._close_fds()
                self._thread = None
                self._stopping = True
                raise
            return self._path

    def stop(self) -> None:
        """Stop the thread and close every descriptor (idempotent)."""
        with self._lifecycle:
            self._stopping = True
            thread, self._thread = self._thread, None
            if thread is not None:
                self._wake()
                thread.join()
            self.engine.remove_listener(self._wake)
            self._close_fds()

    def __enter__(self) -> 'AdapterProxy':
        """Start (unless started) and return the proxy."""
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        """Stop the proxy."""
        self.stop()

    # ------------------------------------------------------------------ the thread
    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b'\0')
        except OSError:  # full (a wake is pending anyway) or closed
            pass

    def _run(self) -> None:
        poller = select.poll()
        poller.register(self._wake_r, select.POLLIN)
        poller.register(self._master, select.POLLIN)
        poller.register(self._upstream, select.POLLIN)
        try:
            while not self._stopping:
                timeout_s = IDLE_S
                next_s = self.engine.next_event_s()
                if next_s is not None:
                    timeout_s = min(timeout_s, max(0.0, next_s - time.monotonic()))
                events = dict(poller.poll(timeout_s * 1000.0))
                if self._wake_r in events:
                    os.read(self._wake_r, 4096)
                # Servo bytes first: replies that reached the adapter stay ahead of the echo.
                if self._upstream in events and not self._from_servos():
                    poller.unregister(self._upstream)
                if self._master in events:
                    self._from_host()
                self._to_host()
        except BaseException as exc:  # kept for the test to see; the thread must not vanish
            self.error = exc

    def _from_servos(self) -> bool:
        """Move servo bytes into the engine; return False once the upstream hung up."""
        try:
            data = os.read(self._upstream, READ_CHUNK)
        except BlockingIOError:
            return True
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            data = b''
        if not data:  # its master closed: virtual_bus has exited
            self.upstream_lost = True
            return False
        self.engine.servo_bytes(data, time.monotonic())
        return True

    def _from_host(self) -> None:
        try:
            data = os.read(self._master, READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # no client has the slave open; we hold one, so rare
                return
            raise
        if not data:
            return
        baud_bps = tty_speed_bps(self._slave)
        if baud_bps and baud_bps != self._baud_bps:
            set_tty_speed(self._upstream, baud_bps)
            self._baud_bps = baud_bps
        self.engine.host_bytes(data, time.monotonic())
        if not self.upstream_lost:
            self._write_upstream(data)

    def _write_upstream(self, data: bytes) -> None:
        view = memoryview(data)
        deadline_s = time.monotonic() + WRITE_TIMEOUT_S
        writable = select.poll()
        writable.register(self._upstream, select.POLLOUT)
        while view:
            try:
                view = view[os.write(self._upstream, view):]
            except BlockingIOError:
                remaining_s = deadline_s - time.monotonic()
                if remaining_s <= 0.0:
                    return  # the device takes nothing: those bytes are lost, as on a bus
                writable.poll(remaining_s * 1000.0)

    def _to_host(self) -> None:
        self.engine.release_to(self._master, time.monotonic())

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave, self._upstream, self._wake_r, self._wake_w):
            _close_fd(fd)
        self._master = self._slave = self._upstream = self._wake_r = self._wake_w = -1
