"""
The one exception family of the driver, and where exceptions stop.

Two conventions, each in its place. Below the point where a request is answered, a failure is an
exception of this family. The manager's request methods (commands, services) and the node's arm
(trajectories, joint-state and gripper commands) answer with a driver.servo.Result (success, a
message for a person, a value), which is what topics log and services return: no exception
reaches a ROS callback. (A few functions exist to describe something for a log line, such as
what a torque-off missed; their text is a report, not an error.)

Every error the package raises is a DriverError, carrying the servo id (None when no single
servo is concerned) and the servo's status error code (None when it did not answer with one).
The siblings say what the caller can do about it:

- PortError: the adapter is gone or cannot be opened; nothing on this bus works until it is
  back. Deliberately not a CommError, so `except CommError` never swallows a lost port.
- CommError: one transaction failed (no reply, a corrupt one, or an error status); the bus
  itself is fine and trying again may work.
- ConfigurationError: a configuration (file, parameter, the servo found at configure) the
  driver refuses; nothing was written.
- Refused: a request refused as it stands (wrong state, stop requested); try again later.
  BadRequest: refused for what it says (an unknown joint, a NaN, arrays of other lengths):
  nothing was done, and sending it again changes nothing.
"""

from typing import Optional


class DriverError(Exception):
    """Base of every error of the driver: a message, the servo concerned, its error code."""

    def __init__(self, message: str, servo_id: Optional[int] = None,
                 code: Optional[int] = None) -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.code = code


class PortError(DriverError):
    """The serial port cannot be opened, or was lost (adapter unplugged)."""


class CommError(DriverError):
    """One transaction on a working bus failed."""


class CommTimeout(CommError, TimeoutError):
    """No (complete, matching) status packet arrived before the deadline."""


class CorruptReply(CommError):
    """A status packet from the servo arrived but failed its CRC or framing check."""


class StatusError(CommError):
    """The servo answered with an error code in its status packet."""

    def __init__(self, message: str, servo_id: int, code: int, alert: bool) -> None:
        super().__init__(message, servo_id, code)
        self.alert = alert


class ConfigurationError(DriverError, ValueError):
    """A configuration the driver refuses (a ValueError too: it is bad input)."""


class Refused(DriverError):
    """A request or transition refused as things stand (a servo refused at configure, ...)."""


class BadRequest(Refused, ValueError):
    """A request refused for what it says; nothing was done (a ValueError too: bad input)."""


class Interrupted(Refused):
    """A stop was requested while a long activity (configure, activate) ran."""
