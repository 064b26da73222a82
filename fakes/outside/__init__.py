"""Outside scenes: a perpendicular wall sweep (0.5-3.0 m by 0.25 m) as an active stereo camera (D435-like) records
it, rendered from first principles, each scene the base physics plus one physical effect, written as a folder that
`rig import` reads with an answer.json beside it.

Written for issue 49 WITHOUT reading rig's effects, models, simulation, diagnosis or its other fakes, so that these
scenes share none of their assumptions. Sources: Huber, Hinzmann, Siegwart, Matthies, "Cubic Range Error Model for
Stereo Vision with Illuminators" (Poisson shot noise, Matthies' disparity variance sigma_d^2 = sigma^2 / sum I'^2,
Z = f b / d, the projector's light falling as Z^-2); Intel RealSense D400 datasheet and the Framos D435e manual
(projector: VCSEL, 850 nm, 360 mW, 86 x 57 deg; f/2.0; 50 mm baseline); Intel's white papers "Subpixel Linearity
Improvement for D400" (f = 0.5 X_res / tan(HFOV/2), HFOV 90 deg) and "Tuning depth cameras for best performance";
optics texts for the camera equation and the cosine-fourth law (Smith, "Modern Optical Engineering"); Newton's law
of cooling for the warm-up; librealsense's rs_device.h (tare and focal-length self-calibration) for the calibration
errors. The physics of each step is in the module that computes it; README.md lists the scenes.

    from fakes.outside import SCENES
    folder = SCENES["gaussian_spot"](1, Path("scenes"))     # scenes/gaussian_spot-seed1/ + .answer.json
"""

from .scenes import SCENES

__all__ = ["SCENES"]
