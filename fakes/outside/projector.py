"""The IR pattern projector as a point source of radiant intensity J(theta) (W/sr), and the irradiance it delivers
on a flat wall perpendicular to the camera's axis.

Irradiance from a point source (radiometry; e.g. McCluskey, "Introduction to Radiometry and Photometry", or any optics
text): E = J(theta) cos(theta_i) / R^2, with R the distance from the source to the wall point and theta_i the angle of
incidence. For a source at (x_p, 0, 0) facing +z and a wall at z = Z: cos(theta_i) = cos(theta) = Z / R, so
E = J(theta) Z / R^3. D435 datasheet (Framos D435e manual sec. 3.3): VCSEL projector, 850 nm, 360 mW average optical
power, field of projection 86 deg x 57 deg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def rectangular_field_sr(h_deg: float, v_deg: float) -> float:
    """Solid angle of a rectangular pyramid of full angles h x v: 4 asin(sin(h/2) sin(v/2)) (sr)."""
    return 4.0 * np.arcsin(np.sin(np.radians(h_deg) / 2) * np.sin(np.radians(v_deg) / 2))


@dataclass(frozen=True)
class Projector:
    """power_w: optical power during the exposure; x_m: lateral offset from the left imager (the depth origin);
    beam_width_deg: None for a beam of uniform radiant intensity over the field of projection, else the Gaussian
    width w of J(theta) = J_peak exp(-theta^2 / 2 w^2), normalised to the same total power."""

    power_w: float = 0.36
    field_h_deg: float = 86.0
    field_v_deg: float = 57.0
    x_m: float = 0.0
    beam_width_deg: float | None = None

    def peak_intensity_w_sr(self) -> float:
        """J on the projector's axis (W/sr): P / Omega_FOP for the uniform beam; for the Gaussian beam
        P / (2 pi int_0^{pi/2} exp(-theta^2/2w^2) sin(theta) dtheta)."""
        if self.beam_width_deg is None:
            return self.power_w / rectangular_field_sr(self.field_h_deg, self.field_v_deg)
        w = np.radians(self.beam_width_deg)
        theta = np.linspace(0.0, np.pi / 2, 20001)
        integrand = np.exp(-theta**2 / (2 * w**2)) * np.sin(theta)
        solid_angle_sr = 2 * np.pi * np.sum((integrand[1:] + integrand[:-1]) / 2 * np.diff(theta))
        return self.power_w / solid_angle_sr

    def intensity_w_sr(self, theta_rad: np.ndarray) -> np.ndarray:
        """J(theta): the beam profile in the off-axis angle theta (the field is taken to cover the image)."""
        j0 = self.peak_intensity_w_sr()
        if self.beam_width_deg is None:
            return np.full_like(theta_rad, j0)
        w = np.radians(self.beam_width_deg)
        return j0 * np.exp(-theta_rad**2 / (2 * w**2))

    def wall_irradiance_w_m2(self, x_n: np.ndarray, y_n: np.ndarray, z_m: float) -> np.ndarray:
        """E = J(theta) Z / R^3 at the wall point (x_n Z, y_n Z, Z), R its distance from the projector (W/m^2)."""
        dx = x_n * z_m - self.x_m
        dy = y_n * z_m
        r_m = np.sqrt(dx**2 + dy**2 + z_m**2)
        theta = np.arccos(z_m / r_m)
        return self.intensity_w_sr(theta) * z_m / r_m**3

    def pattern_shift_native_px(self, f_native_px: float, z_m: float) -> float:
        """Parallax of the projected dots in the left image between the wall at Z and at infinity: f x_p / Z (px).
        A projector at the imager (x_p = 0) puts the same dots on the same pixels at every range."""
        return f_native_px * self.x_m / z_m
