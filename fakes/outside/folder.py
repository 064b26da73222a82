"""Writes a sweep as the folder `rig import` reads (docs/import.md): one sub-folder per stop named after its distance
(`0.500m/`) holding `depth.npy` (an (n, H, W) uint16 stack of depth counts, 0 = no data) and `ir_frames.npy` (the left
IR images, (n, H, W) uint8, paired with the depth frames in order), and `rig-import.toml`, the manifest."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def stop_label(z_m: float) -> str:
    return f"{z_m:.3f}m"


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)        # a JSON string is a valid TOML basic string for these values
    return repr(float(f"{float(value):.12g}"))     # 32.0, not 32.00000000000001


def write_manifest(folder: Path, intrinsics: dict, baseline_m: float, depth_unit_m: float, exposure_us: float,
                   gain: float, camera_model: str) -> None:
    keys = {**intrinsics, "baseline_m": baseline_m, "depth_unit_m": depth_unit_m, "projector_on": True,
            "exposure_us": exposure_us, "gain": gain, "camera_model": camera_model,
            "stop_distance_from_name": "(?P<m>[0-9.]+)m"}
    lines = ["# written by fakes.outside: the scene's camera (see the answer.json beside this folder)"]
    lines += [f"{key} = {_toml_value(value)}" for key, value in keys.items()]
    (folder / "rig-import.toml").write_text("\n".join(lines) + "\n")


def write_stop(folder: Path, z_m: float, depth: np.ndarray, ir: np.ndarray) -> None:
    stop = folder / stop_label(z_m)
    stop.mkdir(parents=True, exist_ok=True)
    np.save(stop / "depth.npy", depth)
    np.save(stop / "ir_frames.npy", ir)


def write_answer(path: Path, answer: dict) -> None:
    path.write_text(json.dumps(answer, indent=2, default=_jsonable) + "\n")


def _jsonable(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.random.SeedSequence):
        return {"entropy": value.entropy, "spawn_key": list(value.spawn_key)}
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
