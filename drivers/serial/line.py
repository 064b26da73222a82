"""A serial port carrying lines of ASCII text, with port failures as one-line `StageError`s.

Both serial stages (GRBL, Zaber) talk through it: open with the OS's reasons turned into
fixes, write, read one line against a deadline, and refuse bytes that are not printable
ASCII (a wrong baud rate or electrical noise).
"""

from __future__ import annotations

import errno
import os
import time

import serial

from ..errors import StageError

CABLE = "check the USB cable and that the controller is powered"
#: no reply line of either protocol is longer (GRBL: 128-byte buffers; a status report is under 100)
MAX_LINE = 256


class Clock:
    """The time the serial drivers keep: deadlines read `monotonic()`, waits (polling, settling) call `sleep()`.

    The system's by default. A test gives a line its own (`SerialLine.clock`, with `SerialLine.open_port`:
    tests/exchanges.py, a scripted port in virtual time), so that the drivers' waits take no time."""

    @staticmethod
    def monotonic() -> float:
        return time.monotonic()

    @staticmethod
    def sleep(seconds: float) -> None:
        time.sleep(seconds)


class GarbledReply(StageError):
    """A reply that is not printable ASCII or not in the protocol (wrong baud, noise); `raw` is what came."""

    raw: bytes | str = b""


class SerialLine:
    """A serial port carrying lines of ASCII text; port failures become one-line StageErrors.

    `clock` and `open_port` (pyserial's `serial.Serial` by default) are where the drivers get the time and
    the port: a test replaces both before opening (tests/exchanges.py)."""

    def __init__(self, kind: str, path: str, baud: int, timeout_s: float):
        self.kind, self.path, self.baud, self.timeout_s = kind, path, baud, timeout_s
        self.name = f"{kind} {path}"
        self.clock = Clock()
        self.open_port = serial.Serial
        self._port: serial.Serial | None = None
        #: the start of a line whose end had not arrived by the last deadline (a late reply)
        self._partial = b""

    def error(self, problem: str, fix: str) -> StageError:
        return StageError(f"{self.name}: {problem}; {fix}")

    def open(self) -> None:
        try:
            exclusive = True if os.name == "posix" else None
            self._port = self.open_port(self.path, self.baud, timeout=self.timeout_s, exclusive=exclusive)
        except (serial.SerialException, OSError) as e:
            raise self._open_error(e) from None

    def _open_error(self, e: Exception) -> StageError:
        code = getattr(e, "errno", None)
        if code in (errno.ENOENT, errno.ENXIO, errno.ENODEV):
            return self.error(
                "no such serial port",
                f"check the cable and `ls /dev/ttyUSB* /dev/ttyACM*`, or try without hardware: "
                f"run `rig stage-sim {self.kind}` and use the port it prints",
            )
        if code in (errno.EACCES, errno.EPERM):
            return self.error(
                "permission denied opening the port",
                "add yourself to the dialout group (`sudo usermod -aG dialout $USER`, then log in again)",
            )
        if code in (errno.EAGAIN, errno.EBUSY):
            return self.error(
                "port is in use by another program",
                "close it (G-code sender, Zaber Launcher, screen, minicom, another rig run) and retry",
            )
        return self.error(f"cannot open the port ({one_line(e)})", "check the device path and the cable")

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def _require(self) -> serial.Serial:
        if self._port is None:
            raise self.error("port is not open", "open the stage (use it as a context manager) before using it")
        return self._port

    def _disconnected(self, doing: str, e: Exception) -> StageError:
        self.close()
        return self.error(f"port disconnected while {doing} ({one_line(e)})", f"{CABLE}")

    def write(self, data: bytes, what: str) -> None:
        port = self._require()
        try:
            port.write(data)
        except (serial.SerialException, OSError) as e:
            raise self._disconnected(f"sending {what}", e) from None

    def discard_input(self) -> None:
        port = self._require()
        self._partial = b""
        try:
            port.reset_input_buffer()
        except (serial.SerialException, OSError) as e:
            raise self._disconnected("clearing the input", e) from None

    @property
    def waiting(self) -> bool:
        """True if bytes have arrived that no read has taken yet (or a late line's start is held)."""
        port = self._require()
        try:
            return bool(self._partial) or port.in_waiting > 0
        except (serial.SerialException, OSError) as e:
            raise self._disconnected("reading the input", e) from None

    @property
    def late(self) -> bool:
        """True if the last read ended at its deadline in the middle of a line (its end may still come)."""
        return bool(self._partial)

    def read_line(self, deadline_s: float, what: str) -> str | None:
        """One line without its line end, or None if no whole line arrived by deadline_s.

        A line whose end has not arrived by the deadline is kept, and the next read goes on from it:
        a late line end is not an error (a busy host or controller sends one now and then). Raises
        `GarbledReply` on bytes that are not printable ASCII, or on a line start that grows past any
        reply's length without an end (a wrong baud rate)."""
        port = self._require()
        try:
            port.timeout = max(0.0, deadline_s - self.clock.monotonic())
            raw = self._partial + port.read_until(b"\n")
        except (serial.SerialException, OSError) as e:
            raise self._disconnected(f"waiting for the reply to {what}", e) from None
        self._partial = b""
        if not raw:
            return None
        body = raw.rstrip(b"\r\n")
        if any(b < 0x20 or b > 0x7E for b in body):
            raise self.garbled(raw, what)
        if not raw.endswith(b"\n"):
            if len(raw) > MAX_LINE:
                raise self.garbled(raw, what)
            self._partial = raw
            return None
        return body.decode("ascii")

    def garbled(self, raw: bytes | str, what: str) -> "GarbledReply":
        shown = raw if isinstance(raw, str) else raw[:60]
        error = GarbledReply(
            f"{self.name}: garbled reply {shown!r} to {what}; check that baud={self.baud} matches the controller "
            f"and that the cable is sound and away from motor wiring"
        )
        error.raw = shown
        return error

    def no_reply(self, what: str, timeout_s: float) -> StageError:
        return self.error(f"no reply to {what} within {timeout_s:.1f} s", f"{CABLE}")


def one_line(e: Exception) -> str:
    return " ".join(str(e).split())
