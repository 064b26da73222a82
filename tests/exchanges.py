"""A serial driver tested against the exchanges it should have with its controller, instantly (pymeasure-style).

    with expected_exchanges(stage, [(b"?", b"<Idle|MPos:0.000,0.000,0.000|FS:0,0>\\r\\n"), ...]) as port:
        stage.open()
        ...

`ScriptedPort` stands where pyserial's port would (`SerialLine.open_port`) and is given the list of
(write, reply) pairs the driver must have with the controller, in order. Each write must be the next pair's
write, byte for byte, or the test fails there, naming what was written and what was expected; the pair's
reply is then in the input at once. Nothing waits: the port keeps virtual time (`VirtualClock`, which it
gives the driver as `SerialLine.clock`), so a read that finds no line ends at its deadline without sleeping,
a `sleep` moves the clock on, and a reply can be made to arrive later (`Later`). When the block ends, every
pair must have been used.

A reply is bytes, or a list of parts: bytes (with the write), `Later(seconds, bytes)` (that long after the
part before it), `UNPLUG` (the cable is pulled there: every later use of the port fails as pyserial's does).
`push` puts bytes the controller sends unasked (a reset's banner) into the input.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator, Sequence, Union

import serial


class VirtualClock:
    """Time that passes only when told: the port's reads that time out and the driver's sleeps move it on."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now = start_s
        #: every sleep the driver asked for, in order (poll intervals, settling, waits for a hold)
        self.sleeps: list[float] = []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += max(0.0, seconds)


@dataclass(frozen=True)
class Later:
    """Reply bytes that arrive `after_s` after the part before them (the write, for the first part)."""

    after_s: float
    data: bytes


class _Unplug:
    def __repr__(self) -> str:
        return "UNPLUG"


#: as a reply part: the cable is pulled there
UNPLUG = _Unplug()

Part = Union[bytes, str, Later, _Unplug]
Exchange = tuple[Union[bytes, str], Union[Part, Sequence[Part], None]]


def _bytes(data: bytes | str) -> bytes:
    return data.encode("ascii") if isinstance(data, str) else data


class ScriptedPort:
    """A serial port that expects `exchanges` (write, reply) in order; see the module's docstring."""

    def __init__(self, exchanges: Sequence[Exchange], clock: VirtualClock | None = None) -> None:
        self.exchanges = [(_bytes(write), self._parts(reply)) for write, reply in exchanges]
        self.clock = clock or VirtualClock()
        #: how many exchanges the driver has had so far
        self.done = 0
        #: everything the driver wrote, in order
        self.written: list[bytes] = []
        #: the input: bytes that have arrived and not been read, and (arrival, part) still on their way
        self.input = bytearray()
        self._coming: list[tuple[float, int, bytes | _Unplug]] = []
        self._order = 0
        self._last_arrival = self.clock.now
        self.timeout: float | None = None
        self.path = self.baud = None
        self.is_open = self.unplugged = False
        #: the first unexpected write, kept in case the driver caught the failure
        self.problem: AssertionError | None = None

    @staticmethod
    def _parts(reply) -> list[Part]:
        if reply is None:
            return []
        if isinstance(reply, (bytes, str, Later, _Unplug)):
            return [reply]
        return list(reply)

    # --- what SerialLine uses of a pyserial port ---------------------------------------------------

    def __call__(self, path: str, baud: int, timeout: float | None = None, exclusive: bool | None = None):
        """Open: the driver's `serial.Serial(path, baud, ...)`."""
        self.path, self.baud, self.timeout, self.is_open = path, baud, timeout, True
        return self

    def write(self, data: bytes) -> int:
        self._arrive()
        if self.unplugged:
            raise serial.SerialException("write failed: [Errno 5] Input/output error")
        self.written.append(bytes(data))
        if self.done >= len(self.exchanges):
            self._fail(f"the driver wrote {bytes(data)!r} after the last of the {len(self.exchanges)} exchanges "
                       f"it was expected to have")
        expected, reply = self.exchanges[self.done]
        if bytes(data) != expected:
            self._fail(f"exchange {self.done + 1} of {len(self.exchanges)}: the driver wrote {bytes(data)!r}, "
                       f"but {expected!r} was expected; {self._history()}")
        self.done += 1
        at = self.clock.now
        for part in reply:
            if isinstance(part, Later):
                at += part.after_s
                part = part.data
            self._schedule(at, part if isinstance(part, _Unplug) else _bytes(part))
        return len(data)

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        """Up to and with the next line end, or what came by the timeout (pyserial's: one deadline for the call)."""
        deadline = self.clock.now + (self.timeout or 0.0)
        out = bytearray()
        while True:
            self._arrive()
            if self.unplugged:
                raise serial.SerialException("read failed: [Errno 5] Input/output error")
            end = self.input.find(expected)
            if end >= 0:
                out += self.input[:end + len(expected)]
                del self.input[:end + len(expected)]
                return bytes(out)
            out += self.input
            self.input.clear()
            if not self._coming or self._coming[0][0] > deadline:
                self.clock.now = max(self.clock.now, deadline)
                return bytes(out)
            self.clock.now = max(self.clock.now, self._coming[0][0])

    def reset_input_buffer(self) -> None:
        self._arrive()
        if self.unplugged:
            raise serial.SerialException("[Errno 5] Input/output error")
        self.input.clear()

    @property
    def in_waiting(self) -> int:
        self._arrive()
        if self.unplugged:
            raise serial.SerialException("[Errno 5] Input/output error")
        return len(self.input)

    def close(self) -> None:
        self.is_open = False

    # --- for tests ----------------------------------------------------------------------------------

    def push(self, data: bytes | str, after_s: float = 0.0) -> None:
        """Bytes the controller sends unasked, arriving `after_s` from now."""
        self._schedule(self.clock.now + after_s, _bytes(data))

    def unplug(self) -> None:
        """Pull the cable now."""
        self._schedule(self.clock.now, UNPLUG)

    def check_done(self) -> None:
        """Fail if a write was unexpected or an expected exchange never came."""
        if self.problem is not None:
            raise self.problem
        if self.done < len(self.exchanges):
            left = [w for w, _ in self.exchanges[self.done:self.done + 3]]
            raise AssertionError(f"the driver had {self.done} of the {len(self.exchanges)} exchanges expected; "
                                 f"the next would have been {left}{' ...' if self.done + 3 < len(self.exchanges) else ''}")

    def attach(self, stage) -> None:
        """Make `stage` (GrblStage or ZaberStage, not yet opened) open this port and keep this port's time."""
        line = getattr(stage.link, "line", stage.link)
        line.open_port, line.clock = self, self.clock

    # --- inside -------------------------------------------------------------------------------------

    def _schedule(self, at: float, part: bytes | _Unplug) -> None:
        """One byte stream: nothing overtakes what was sent before it (a late line end comes before the reply
        to a later request)."""
        self._last_arrival = max(at, self._last_arrival)
        self._order += 1
        self._coming.append((self._last_arrival, self._order, part))

    def _arrive(self) -> None:
        while self._coming and self._coming[0][0] <= self.clock.now and not self.unplugged:
            _, _, part = self._coming.pop(0)
            if isinstance(part, _Unplug):
                self.unplugged = True
            else:
                self.input += part

    def _history(self) -> str:
        recent = self.written[-4:-1]
        return f"the writes before it: {recent}" if recent else "it was the first write"

    def _fail(self, message: str) -> None:
        error = AssertionError(message)
        if self.problem is None:
            self.problem = error
        raise error


@contextmanager
def expected_exchanges(stage, exchanges: Sequence[Exchange], clock: VirtualClock | None = None
                       ) -> Iterator[ScriptedPort]:
    """`stage` talks to a `ScriptedPort` expecting `exchanges` inside the block; at its end, all must have been had.
    If the block fails after the driver caught an unexpected write's failure, that failure is raised instead."""
    port = ScriptedPort(exchanges, clock)
    port.attach(stage)
    try:
        yield port
    except BaseException as e:
        if port.problem is not None and e is not port.problem:
            raise port.problem from e
        raise
    port.check_done()
