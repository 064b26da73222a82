"""What the simulated serial controllers share: a pseudo-terminal, a serving thread, faults,
and a carriage that takes time to move.

A simulator opens a pty pair, keeps both ends, and answers on the master end from a
background thread; drivers open the slave end (`.port`, e.g. /dev/pts/5) with pyserial just
as they would open /dev/ttyUSB0.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from dataclasses import dataclass
from typing import Callable

import numpy as np

#: faults every simulator accepts in `inject()`
COMMON_FAULTS = ("drop_reply", "noise", "unplug", "position_error")


@dataclass
class Move:
    """One motion of the carriage: from start_mm towards end_mm, starting at t0_s."""

    start_mm: float
    end_mm: float
    t0_s: float
    speed_mm_s: float
    #: why the carriage stops at end_mm: "arrived", or a fault ("limit", "stall")
    outcome: str = "arrived"
    #: where the carriage really ends (end_mm plus an injected position error)
    final_mm: float | None = None
    #: acceleration and deceleration, mm/s^2 (None: full speed at once)
    accel_mm_s2: float | None = None

    def _profile(self) -> tuple[float, float, float]:
        """(peak speed mm/s, ramp time s, total time s) of the trapezoid (or triangle) velocity profile."""
        d = abs(self.end_mm - self.start_mm)
        if not self.accel_mm_s2:
            return self.speed_mm_s, 0.0, d / self.speed_mm_s
        a = self.accel_mm_s2
        v = min(self.speed_mm_s, (a * d) ** 0.5)  # a triangle when the move is too short to reach full speed
        ramp = v / a
        return v, ramp, 2 * ramp + (d - v * ramp) / v if v > 0 else 0.0

    def travelled_mm(self, now_s: float) -> float:
        d = abs(self.end_mm - self.start_mm)
        t = max(0.0, now_s - self.t0_s)
        v, ramp, total = self._profile()
        if t >= total:
            return d
        if not self.accel_mm_s2:
            return min(d, t * v)
        a = self.accel_mm_s2
        if t < ramp:
            return 0.5 * a * t * t
        if t < total - ramp:
            return 0.5 * v * ramp + v * (t - ramp)
        left = total - t
        return d - 0.5 * a * left * left

    def position_mm(self, now_s: float) -> float:
        return self.start_mm + np.copysign(self.travelled_mm(now_s), self.end_mm - self.start_mm)

    def done(self, now_s: float) -> bool:
        return now_s - self.t0_s >= self._profile()[2]

    def speed_at(self, now_s: float) -> float:
        """The carriage's speed at now_s, mm/s (the slope of the trapezoid)."""
        t = max(0.0, now_s - self.t0_s)
        v, ramp, total = self._profile()
        if t >= total:
            return 0.0
        if not self.accel_mm_s2:
            return v
        return min(v, self.accel_mm_s2 * t, self.accel_mm_s2 * (total - t))


@dataclass
class Stopping:
    """The carriage braking to a halt at accel_mm_s2 from speed_mm_s (a feed hold): v^2 / 2a further on."""

    start_mm: float
    sign: float
    t0_s: float
    speed_mm_s: float
    accel_mm_s2: float
    outcome: str = "held"

    @property
    def end_mm(self) -> float:
        return self.start_mm + self.sign * self.speed_mm_s ** 2 / (2.0 * self.accel_mm_s2)

    @property
    def final_mm(self) -> float:
        return self.end_mm

    def position_mm(self, now_s: float) -> float:
        t = min(max(0.0, now_s - self.t0_s), self.speed_mm_s / self.accel_mm_s2)
        return self.start_mm + self.sign * (self.speed_mm_s * t - 0.5 * self.accel_mm_s2 * t * t)

    def done(self, now_s: float) -> bool:
        return now_s - self.t0_s >= self.speed_mm_s / self.accel_mm_s2


class Carriage:
    """The simulated carriage on a rail from 0 to travel_mm, with limit switches at both ends."""

    def __init__(self, travel_mm: float, speed_mm_s: float, start_mm: float, accel_mm_s2: float | None = None):
        self.travel_mm = travel_mm
        self.speed_mm_s = speed_mm_s
        self.accel_mm_s2 = accel_mm_s2
        self._rest_mm = start_mm
        self.move: Move | Stopping | None = None

    def position_mm(self, now_s: float) -> float:
        return self.move.position_mm(now_s) if self.move else self._rest_mm

    def moving(self) -> bool:
        return self.move is not None

    def start(self, target_mm: float, now_s: float, *, stop_at_mm: float | None = None,
              stop_outcome: str = "stall", error_mm: float = 0.0, speed_mm_s: float | None = None) -> None:
        """Head for target_mm. Beyond the rail the carriage stops at the end ("limit");
        stop_at_mm stops it early with stop_outcome; error_mm offsets where it really ends."""
        start = self.position_mm(now_s)
        end, outcome = target_mm, "arrived"
        if not 0.0 <= target_mm <= self.travel_mm:
            end, outcome = min(max(target_mm, 0.0), self.travel_mm), "limit"
        if stop_at_mm is not None and min(start, end) <= stop_at_mm <= max(start, end):
            end, outcome = stop_at_mm, stop_outcome
        final = end + error_mm if outcome == "arrived" else end
        self.move = Move(start, end, now_s, speed_mm_s or self.speed_mm_s, outcome, final, self.accel_mm_s2)

    def place(self, position_mm: float) -> None:
        """Put the carriage at rest at position_mm (a move too short to simulate)."""
        self._rest_mm = position_mm
        self.move = None

    def stop(self, now_s: float) -> None:
        """Halt at once wherever the carriage is."""
        self._rest_mm = self.position_mm(now_s)
        self.move = None

    def brake(self, now_s: float) -> None:
        """Decelerate to a halt at accel_mm_s2 (a feed hold); at once without an acceleration."""
        move = self.move
        if not isinstance(move, Move) or not self.accel_mm_s2:
            self.stop(now_s)
            return
        speed = move.speed_at(now_s)
        if speed <= 0.0:
            self.stop(now_s)
            return
        sign = 1.0 if move.end_mm >= move.start_mm else -1.0
        stopping = Stopping(move.position_mm(now_s), sign, now_s, speed, self.accel_mm_s2)
        if not 0.0 <= stopping.end_mm <= self.travel_mm:  # the end of the rail stops it first
            self.stop(now_s)
            return
        self.move = stopping

    def update(self, now_s: float) -> str | None:
        """Finish a move whose time is up; return its outcome, or None while moving or at rest."""
        if self.move is None or not self.move.done(now_s):
            return None
        move, self.move = self.move, None
        self._rest_mm = move.final_mm if move.final_mm is not None else move.end_mm
        return move.outcome


class PtyController:
    """A simulated controller on a pseudo-terminal, served by a background thread.

    Subclasses implement `handle_bytes()` (bytes from the driver) and `tick()` (time passing)
    and reply with `send_line()`. Use as a context manager, or call start() and stop().
    Faults are set with `inject()`; `commands` and `replies` log the traffic for tests.
    """

    kind = "pty"
    faults: tuple[str, ...] = COMMON_FAULTS

    def __init__(self, *, tick_s: float = 0.005, seed: int = 0):
        self.tick_s = tick_s
        self.port = ""
        self.commands: list[str] = []
        self.replies: list[str] = []
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._pending: dict[str, dict] = {}
        self._position_callbacks: list[Callable[[float], None]] = []
        self._master = self._slave = -1
        self._wake_r = self._wake_w = -1
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()

    # --- lifetime -------------------------------------------------------------------------

    def start(self) -> "PtyController":
        """Open the pty and serve it; does nothing if already serving."""
        if self.running:
            return self
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)  # a full buffer loses bytes, as a real UART would
        self.port = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._stopping.clear()
        self._thread = threading.Thread(
            target=self._serve, args=(self._master, self._slave, self._wake_r, self._wake_w),
            name=f"{self.kind}-sim {self.port}", daemon=True,
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty; the port disappears. start() again serves a new pty."""
        self._stopping.set()
        with self._lock:
            if self._wake_w >= 0:
                os.write(self._wake_w, b"x")
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def __enter__(self) -> "PtyController":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # --- faults and hooks -------------------------------------------------------------------

    def inject(self, fault: str, **params: float) -> None:
        """Arm a fault. Common ones: drop_reply (ignore the next `count` commands), noise
        (garble the next `count` replies), unplug (close the pty now), position_error
        (the next `count` moves end `mm` off target)."""
        if fault not in self.faults:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(self.faults)}")
        if fault == "unplug":
            self.stop()
            return
        with self._lock:
            self._pending[fault] = {"count": 1, **params}

    def clear_faults(self) -> None:
        with self._lock:
            self._pending.clear()

    def on_position(self, callback: Callable[[float], None]) -> None:
        """Call `callback(position_mm)` each time the carriage comes to rest."""
        self._position_callbacks.append(callback)

    # --- for subclasses -------------------------------------------------------------------

    def take_fault(self, fault: str) -> dict | None:
        """Use up one occurrence of an armed fault; its parameters, or None if not armed."""
        with self._lock:
            params = self._pending.get(fault)
            if params is None:
                return None
            params["count"] -= 1
            if params["count"] <= 0:
                del self._pending[fault]
            return params

    def drop_command(self, text: str) -> bool:
        """Log a received command; True if an armed drop_reply fault swallows it."""
        self.commands.append(text)
        return self.take_fault("drop_reply") is not None

    def send_line(self, text: str) -> None:
        """Send one reply line (CR LF added), garbled if a noise fault is armed."""
        data = text.encode("ascii")
        if self.take_fault("noise") is not None:
            data = self._garble(data)
            text = data.decode("latin-1")
        self.replies.append(text)
        self.write(data + b"\r\n")

    def write(self, data: bytes) -> None:
        with self._lock:
            if self._master < 0:
                return
            try:
                os.write(self._master, data)
            except OSError:
                pass

    def rested(self, position_mm: float) -> None:
        for callback in self._position_callbacks:
            callback(position_mm)

    def handle_bytes(self, data: bytes, now_s: float) -> None:
        raise NotImplementedError

    def tick(self, now_s: float) -> None:
        """Let time pass: finish moves, raise alarms."""

    # --- internals ----------------------------------------------------------------------------

    def _garble(self, data: bytes) -> bytes:
        """Line noise: flip high bits and scramble bytes, never adding a line end."""
        noisy = bytearray(data or b"?")
        for i in range(len(noisy)):
            if self._rng.random() < 0.5:
                noisy[i] = (noisy[i] ^ int(self._rng.integers(0x80, 0x100))) & 0xFF
        noisy[0] |= 0x80
        return bytes(b if b not in (0x0A, 0x0D) else 0xBF for b in noisy)

    def _serve(self, master: int, slave: int, wake_r: int, wake_w: int) -> None:
        try:
            while not self._stopping.is_set():
                ready, _, _ = select.select([master, wake_r], [], [], self.tick_s)
                now = time.monotonic()
                if master in ready:
                    try:
                        data = os.read(master, 4096)
                    except OSError:
                        data = b""
                    if data:
                        with self._lock:
                            self.handle_bytes(data, now)
                with self._lock:
                    self.tick(now)
        finally:
            with self._lock:
                self._master = self._slave = self._wake_r = self._wake_w = -1
                for fd in (master, slave, wake_r, wake_w):
                    os.close(fd)
