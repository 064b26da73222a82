"""What a RealSense frame's metadata says about the settings it was exposed with."""

from __future__ import annotations

#: the per-frame metadata fields the driver reads (rs.frame_metadata_value names)
METADATA_KEYS = ("actual_exposure", "gain_level", "auto_exposure", "frame_emitter_mode", "frame_laser_power_mode",
                 "frame_laser_power")


def projector_state(emitter_mode: float | None, laser_power_mode: float | None, laser_power_mw: float | None) -> bool:
    """Whether a frame was exposed with the projector on, from its metadata.

    frame_emitter_mode (newer firmware): 0 = all emitters off, 1 = laser, 2 = laser auto, 3 = LED.
    frame_laser_power_mode (D4xx): 1 = emitter on, 0 = off. frame_laser_power: mW, 0 = off.
    """
    if emitter_mode is not None:
        on = emitter_mode != 0
    elif laser_power_mode is not None:
        on = laser_power_mode != 0
    else:
        on = laser_power_mw is None or laser_power_mw > 0
    if laser_power_mw is not None and laser_power_mw <= 0:
        on = False
    return bool(on)
