"""The IR imager: the wall's radiance to photo-electrons (the camera equation), and the 8-bit IR image it records
(Poisson shot noise, Gaussian read noise, a linear conversion gain, rounding, clipping at full scale).

Camera equation (Smith, "Modern Optical Engineering", image irradiance; Slater, "Remote Sensing: Optics and Optical
Systems"): E_image = pi L T / (4 N^2) * RI(phi), with L the scene radiance, T the optics' transmission, N the f-number
and RI the relative illumination at field angle phi (1 for a lens with flat illumination; cos^4(phi) for natural
vignetting, the cosine-fourth law). Electrons: S = E_image A_pix t_exp QE lambda / (h c). Shot noise is Poisson
(Huber et al. eq. 1; Theuwissen, "Solid-State Imaging with Charge-Coupled Devices"); read noise is a signal-independent
Gaussian floor. D435 datasheet: depth lens f/2.0, 3 um pixels, 850 nm. The D4xx IR stream is Y8 (8-bit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PLANCK_J_S = 6.62607015e-34
LIGHT_M_S = 299792458.0


@dataclass(frozen=True)
class Imager:
    f_number: float = 2.0
    optics_transmission: float = 0.8      # lens and 850 nm band-pass filter (assumed)
    pixel_pitch_m: float = 3.0e-6
    exposure_us: float = 8500.0
    quantum_efficiency: float = 0.30      # silicon at 850 nm (assumed)
    wavelength_m: float = 850e-9
    read_noise_e: float = 5.0
    full_scale_e: float = 8000.0          # electrons at the Y8 stream's top code, 255 DN (gain 16, the lowest)
    full_scale_dn: int = 255
    cos4_vignetting: bool = False

    def relative_illumination(self, cos_phi: np.ndarray) -> np.ndarray:
        """RI(phi): cos^4(phi) (natural vignetting, the cosine-fourth law) or 1 (a lens designed flat)."""
        return cos_phi**4 if self.cos4_vignetting else np.ones_like(cos_phi)

    def electrons(self, radiance_w_m2_sr: np.ndarray, cos_phi: np.ndarray) -> np.ndarray:
        """S = pi L T RI / (4 N^2) * A_pix * t_exp * QE * lambda / (h c): mean photo-electrons in the exposure."""
        image_irradiance = (np.pi * radiance_w_m2_sr * self.optics_transmission / (4 * self.f_number**2)
                            * self.relative_illumination(cos_phi))
        energy_j = image_irradiance * self.pixel_pitch_m**2 * self.exposure_us * 1e-6
        return energy_j * self.quantum_efficiency * self.wavelength_m / (PLANCK_J_S * LIGHT_M_S)

    @property
    def dn_per_electron(self) -> float:
        return self.full_scale_dn / self.full_scale_e

    def ir_frames(self, rng: np.random.Generator, signal_e: np.ndarray, n_frames: int) -> np.ndarray:
        """(n, H, W) uint8: DN = clip(round(K (Poisson(S) + N(0, read^2))), 0, full scale), K = 255 / full_scale_e."""
        shape = (n_frames, *signal_e.shape)
        electrons = rng.poisson(signal_e, size=shape) + rng.normal(0.0, self.read_noise_e, size=shape)
        dn = np.rint(electrons * self.dn_per_electron)
        return np.clip(dn, 0, self.full_scale_dn).astype(np.uint8)
