"""Recorded bags (RealSense .bag, ROS 1/ROS 2 .bag/.db3/.mcap) read as a camera: a `rig import` source.

`contents` opens a bag with rosbags and reads what it says (depth topic, camera_info, the RealSense
recorder's options, device info and per-frame metadata), `camera` replays bags to the runner, one per
stop. `camera_topics` and `stereo_baseline` tell a bag's cameras apart; `depth_messages` (with `rvl`) decodes a
depth message, raw or compressedDepth, and `metric_depth` turns depth in metres into counts. The import itself (stops, plan, runner, provenance) is `protocols.bag_import`. See docs/import.md.
"""

from .camera import BagCamera, BagStop
from .contents import BAG_SUFFIXES, BagFacts, is_bag, read_facts

__all__ = ["BagCamera", "BagStop", "BAG_SUFFIXES", "BagFacts", "is_bag", "read_facts"]
