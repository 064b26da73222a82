"""Device interfaces and the drivers for real hardware.

`drivers.camera` and `drivers.stage` define what every camera and stage must offer;
real drivers (serial stages, RealSense, OAK-D) live beside them, simulated ones in `fakes/`.
"""
