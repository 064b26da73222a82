"""The simulated scene shared by the fake camera and the fake stages: a flat matte wall."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Wall:
    """A flat matte wall.

    distance_m: camera-to-wall distance along the optical axis, in m.
    tilt_deg: rotation of the wall about the camera's vertical (y) axis; 0 = perpendicular
    to the optical axis. Positive tilt makes the right side of the image (u > cx) nearer.
    roughness_m: RMS relief of the wall surface along Z (fixed per pixel), m.
    """

    distance_m: float = 1.0
    tilt_deg: float = 0.0
    roughness_m: float = 0.0005


@dataclass
class FakeWorld:
    """Shared state of a simulated rig: where the wall is, and the simulated clock in s."""

    wall: Wall
    time_s: float = 0.0

    @classmethod
    def perpendicular(cls, distance_m: float = 1.0) -> "FakeWorld":
        return cls(Wall(distance_m=distance_m))

    def set_distance(self, distance_m: float) -> None:
        self.wall.distance_m = distance_m
