"""Throughput of the acquisition hot path, as ratios against baselines measured in the same run.

  python benchmarks/streaming.py [--width 848] [--frames 200]

Per frame at the given resolution it times:
  stats      rig.stats.PixelMomentAccumulator.add (exact streaming moments, 4 power sums)
  fake       fakes.camera.FakeCamera rendering one depth frame (the paper's noise physics)
and two baselines on the same arrays:
  copy       numpy copying the frame to int64 (the least any per-frame pass costs)
  welford    a textbook float64 Welford mean/variance update (2 moments only)
Ratios (time / copy, time / welford) are what to compare across machines; absolute times on
these 2-core machines are noisy. A full sweep is 11 stops x 300 frames = 3300 frames.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.camera import CameraSettings  # noqa: E402
from fakes.camera import FakeCamera  # noqa: E402
from fakes.world import FakeWorld  # noqa: E402
from protocols.stats import PixelMomentAccumulator  # noqa: E402


def best_of(fn, frames: list[np.ndarray], repeats: int = 3) -> float:
    """Best mean seconds per frame over `repeats` passes."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for f in frames:
            fn(f)
        best = min(best, (time.perf_counter() - t0) / len(frames))
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=848)
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    h = round(args.width * 480 / 848)
    world = FakeWorld.perpendicular(2.0)
    cam = FakeCamera(world, width=args.width, height=h, depth_scale_m=1e-4)
    with cam:
        cam.configure(CameraSettings())
        frames = [f.depth for f in cam.frames(args.frames)]
        t0 = time.perf_counter()
        for _ in cam.frames(args.frames):
            pass
        t_fake = (time.perf_counter() - t0) / args.frames

    acc = PixelMomentAccumulator((h, args.width), 1e-4)
    t_stats = best_of(acc.add, frames)
    t_copy = best_of(lambda f: f.astype(np.int64), frames)
    state = {"n": np.zeros((h, args.width)), "mean": np.zeros((h, args.width)), "m2": np.zeros((h, args.width))}

    def welford(f: np.ndarray) -> None:
        x = f.astype(np.float64)
        state["n"] += 1
        delta = x - state["mean"]
        state["mean"] += delta / state["n"]
        state["m2"] += delta * (x - state["mean"])

    t_welford = best_of(welford, frames)
    print(f"{args.width}x{h} px, {args.frames} frames; seconds per frame and ratios to the baselines measured now:")
    for name, t in (("copy (baseline)", t_copy), ("welford (baseline)", t_welford), ("rig stats", t_stats),
                    ("fake camera", t_fake)):
        print(f"  {name:<20} {t * 1e3:8.2f} ms   x{t / t_copy:6.1f} copy   x{t / t_welford:5.2f} welford")
    print(f"  a full sweep (3300 frames): stats {3300 * t_stats:.0f} s, fake camera {3300 * t_fake:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
