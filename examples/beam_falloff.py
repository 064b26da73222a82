"""A projector whose beam is brightest on its axis: its light falls off as cos^n of the off-axis angle.

Load it with --effects examples/beam_falloff.py (rig fit, rig compare, rig diagnose, rig tui).
"""

from rig.models import Param, TermEffect, register


@register
class BeamFalloff(TermEffect):
    """The projector's beam falls off as cos^n of the off-axis angle, so the shot-noise variance grows as cos^-n."""

    name = "beam_falloff"
    stage = "illumination"
    params = (Param("n", 2.0, 0.0, 12.0, "1", "exponent of the beam's cos^n fall-off"),)
    signature = "the error grows towards the image corners, more than the slant range explains"

    def term(self, c, n):
        return c.cos_off_axis ** -n
