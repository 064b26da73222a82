"""Time over the run, and the disparity drift of a camera warming up.

A cold camera switched on at the run's first frame heats towards equilibrium as a first-order system (Newton's law of
cooling: dT/dt = (T_eq - T) / tau, so T(t) - T_0 = (T_eq - T_0)(1 - exp(-t / tau))). The imagers' relative yaw
follows the mount's temperature linearly, and a yaw delta_alpha shifts every disparity by f delta_alpha (a disparity
offset, the same at every pixel): delta_d(t) = A (1 - exp(-t / tau)). Vendors of stereo cameras document this
self-heating drift of the depth after start-up, settling over minutes (e.g. Mech-Mind's note on temperature drift).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RunClock:
    """Frames at fps; between stops the stage moves and settles for move_s; t = 0 at the run's first frame."""

    fps: float = 30.0
    move_s: float = 5.0

    def frame_times_s(self, stop_index: int, n_frames: int) -> np.ndarray:
        stop_start_s = stop_index * (n_frames / self.fps + self.move_s)
        return stop_start_s + np.arange(n_frames) / self.fps


@dataclass(frozen=True)
class ThermalDrift:
    amplitude_px: float = 0.0     # A, native px (the offset once warm)
    tau_s: float = 240.0

    def offset_px(self, t_s: np.ndarray) -> np.ndarray:
        """delta_d(t) = A (1 - exp(-t / tau)), native px."""
        return self.amplitude_px * (1.0 - np.exp(-np.asarray(t_s, dtype=float) / self.tau_s))
