"""Simulated devices: a stereo depth camera looking at a wall, and a linear stage.

They share a `FakeWorld`, so moving the fake stage (or a simulated serial controller)
moves the wall the fake camera sees. They are the `fake:` kinds (`fakes.kinds`), registered
by entry point like any plugin's, so nothing below the application imports this package.
"""
