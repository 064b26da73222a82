"""Per-pixel sigma images of an exported model (`rig export --sigma-map 0.5,1,2`): a `.npy` stack, the same as a
float32 TIFF with its metadata (tifffile), and a PNG.

Each image is the model's sigma (`rig.noise_model.NoiseModel.sigma`) at every pixel of the depth image for a wall
perpendicular to the optical axis at one range Z: there a pixel's ray meets the wall at the angle whose cosine is
1 / sqrt(1 + rho^2), which is what incidence terms get. A model whose terms need a measured input per pixel
(brightness, ambient light, drift) has no map without it: one line says so.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..noise_model import NoiseModel
from .output_file import aside, save_figure

#: inputs a map over a perpendicular wall can supply itself
MAP_INPUTS = ("cos_incidence",)


#: the farthest range a sigma map is drawn at (m): beyond it, a range is a number in mm written as metres
FARTHEST_MAP_M = 50.0


def parse_ranges(text: str) -> list[float]:
    """"0.5,1,2" -> [0.5, 1.0, 2.0]; a ValueError naming the option and the fix otherwise."""
    try:
        z = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        z = []
    if not z or not all(np.isfinite(v) and v > 0 for v in z):
        raise ValueError(f"--sigma-map {text!r}: give ranges in metres, comma-separated and above 0, e.g. --sigma-map 0.5,1,2")
    far = [v for v in z if v > FARTHEST_MAP_M]
    if far:  # millimetres written as metres, most likely: a map at 500 m is no stereo camera's
        raise ValueError(f"--sigma-map {text!r}: {far[0]:g} m is beyond any stereo depth camera's range "
                         f"({FARTHEST_MAP_M:g} m); give ranges in metres, e.g. --sigma-map "
                         + ",".join(f"{v / 1000:g}" if v > FARTHEST_MAP_M else f"{v:g}" for v in z))
    return z


#: a map whose spread (max - min) is below this fraction of its mean is written as one value, not drawn: a colour
#: bar over less than 0.1 % shows float rounding, or a model with no term over the image, as a +-10 % pattern
CONSTANT_SPREAD = 1e-3


def is_constant(image_m) -> bool:
    """Whether a sigma map (m) is constant over the image within `CONSTANT_SPREAD` of its mean."""
    finite = np.asarray(image_m)[np.isfinite(image_m)]
    return finite.size > 0 and np.ptp(finite) <= CONSTANT_SPREAD * abs(float(finite.mean()))


def constant_text(image_m) -> str:
    """A constant map's value in mm, with the spread it is constant within."""
    return f"{1e3 * float(np.nanmean(image_m)):.4g} mm (spread below {100 * CONSTANT_SPREAD:g} %)"


def map_problem(inputs: tuple[str, ...] | list[str]) -> str | None:
    """Why a model whose terms need `inputs` (`NoiseModel.inputs`) has no sigma map, or None."""
    missing = [n for n in inputs if n not in MAP_INPUTS]
    if missing:
        return (f"the model's terms need {', '.join(missing)} at each pixel, which a map over a wall does not have; "
                f"export a model without them, or evaluate sigma with your own {', '.join(missing)} (rig.noise_model)")
    return None


def sigma_maps(model: NoiseModel, ranges_m: list[float]) -> np.ndarray:
    """sigma, m, as (len(ranges_m), height, width) over the depth image, a perpendicular wall at each range."""
    k = model.doc["camera"]["intrinsics"]
    v, u = np.mgrid[0:k["height"], 0:k["width"]].astype(float)
    rho2 = ((u - k["cx"]) / k["fx"]) ** 2 + ((v - k["cy"]) / k["fy"]) ** 2
    extra = {"cos_incidence": 1.0 / np.sqrt(1.0 + rho2)} if "cos_incidence" in model.inputs else {}
    return np.stack([model.sigma(np.full(u.shape, z), u, v, **extra) for z in ranges_m])


def tiff_metadata(model: NoiseModel, ranges_m: list[float]) -> dict:
    """What the TIFF says about its pages (tifffile's JSON image description): what and in which unit, the model, the
    camera it was fitted to and each page's range."""
    cam = model.doc["camera"]
    return {"quantity": "sigma of a depth sample (rig.noise-model/1, docs/noise-model.md)", "unit": "m",
            "model": model.doc["model"], "noise_model_file": model.source, "z_m": [float(z) for z in ranges_m],
            "scene": "a wall perpendicular to the optical axis at each page's z_m",
            "camera": {"model": cam["model"], "serial": cam["serial"], "intrinsics": cam["intrinsics"],
                       "fb_px_m": cam["fb_px_m"], "depth_unit_m": cam["depth_unit_m"]}}


def write_sigma_maps(model: NoiseModel, ranges_m: list[float], out_stem: Path) -> tuple[Path, Path, Path]:
    """Write OUT_STEM.npy (sigma in m, ranges x rows x columns), OUT_STEM.tif (the same as float32, a page a range,
    with `tiff_metadata`) and OUT_STEM.png (one panel a range, in mm, each with its colour bar); return the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import tifffile

    maps = sigma_maps(model, ranges_m)
    npy, tif, png = (out_stem.with_name(out_stem.name + suffix) for suffix in (".npy", ".tif", ".png"))
    image = io.BytesIO()  # numpy writes a real file through C stdio, whose failed flush it does not report (a full
    np.save(image, maps)  # disk left a part of the .npy in place): the bytes are written by Python instead
    with aside(npy) as tmp, open(tmp, "wb") as f:  # whole or not at all (rig.reports.output_file)
        f.write(image.getvalue())
    # float32: sigma rounded to 2^-24 relatively (6e-8, 0.6 nm in 10 mm), what image tools and ROS's 32FC1 take
    with aside(tif) as tmp, open(tmp, "wb") as f:  # a file object: tifffile resolves a path it is given
        tifffile.imwrite(f, maps.astype(np.float32), photometric="minisblack",
                         metadata=tiff_metadata(model, ranges_m))
    fig, axes = plt.subplots(1, len(ranges_m), figsize=(4.2 * len(ranges_m), 3.2), squeeze=False)
    for ax, z, image in zip(axes[0], ranges_m, maps):
        ax.set_title(f"Z = {z:g} m")
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
        if is_constant(image):  # a colour bar would stretch rounding over the whole scale
            ax.set_xlim(0, image.shape[1])
            ax.set_ylim(image.shape[0], 0)
            ax.set_aspect("equal")  # the image's shape, as imshow draws it
            ax.text(0.5, 0.5, f"constant over the image:\n{constant_text(image)}", transform=ax.transAxes,
                    ha="center", va="center", fontsize=11)
            continue
        shown = ax.imshow(image * 1e3, cmap="viridis", origin="upper")
        fig.colorbar(shown, ax=ax, label="sigma (mm)", shrink=0.85)
    fig.suptitle(f"{model.doc['model']}: sigma of a depth sample, a wall perpendicular to the axis", fontsize=10)
    fig.tight_layout()
    save_figure(fig, png, dpi=100)
    plt.close(fig)
    return npy, tif, png
