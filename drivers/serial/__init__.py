"""Linear stages on a serial port: GRBL 1.1 (G-code) and Zaber (ASCII).

`line` carries text lines over pyserial, `rail` maps camera-to-wall distance to the axis,
`grbl` and `zaber` speak each controller's protocol (their codes in `grbl_codes`, `zaber_codes`).
"""

from .grbl import GrblStage
from .line import SerialLine
from .rail import Rail
from .zaber import ZaberStage

__all__ = ["GrblStage", "ZaberStage", "SerialLine", "Rail"]
