"""drivers/bag/ros1.py: a ROS 1 bag read with its message definitions parsed once per process, checked against
rosbags' own AnyReader (which parses them at every open) on the real D435 bag and on bags rosbags writes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from drivers.bag import ros1
from drivers.bag.contents import read_facts
from drivers.errors import FolderImportError

ROOT = Path(__file__).resolve().parents[1]
REAL_BAG = ROOT / "tests" / "vendor" / "real" / "realsense" / "single_depth_color_640x480.bag"


def _fields(msg) -> object:
    """A deserialized message as plain values (arrays as lists), to compare two readers' messages."""
    if hasattr(msg, "__dataclass_fields__"):
        return {name: _fields(getattr(msg, name)) for name in msg.__dataclass_fields__}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [_fields(x) for x in msg]
    return msg


def test_every_message_of_the_real_bag_is_what_rosbags_anyreader_reads():
    from rosbags.highlevel import AnyReader

    with AnyReader([REAL_BAG]) as theirs:
        want = [(c.topic, c.msgtype, t, _fields(theirs.deserialize(raw, c.msgtype)))
                for c, t, raw in theirs.messages(connections=theirs.connections)]
        topics = sorted((c.topic, c.msgtype, c.msgcount) for c in theirs.connections)
    with ros1.Ros1Bag(REAL_BAG) as ours:
        got = [(c.topic, c.msgtype, t, _fields(ours.deserialize(raw, c.msgtype)))
               for c, t, raw in ours.messages(ours.connections)]
        assert sorted((c.topic, c.msgtype, c.msgcount) for c in ours.connections) == topics
    assert len(want) > 100 and got == want


def test_the_definitions_are_parsed_once_per_file_and_again_when_it_changes(tmp_path, monkeypatch):
    import rosbags.typesys

    bag = tmp_path / "d435.bag"
    bag.write_bytes(REAL_BAG.read_bytes())
    parsed = []
    real = rosbags.typesys.get_types_from_msg
    monkeypatch.setattr(rosbags.typesys, "get_types_from_msg", lambda *a: parsed.append(a[1]) or real(*a))
    for _ in range(3):
        with ros1.Ros1Bag(bag) as b:
            n = len(b.connections)
    assert len(parsed) == n > 10  # the first open parsed each connection's definition; the next two none
    bag.write_bytes(REAL_BAG.read_bytes())  # written again, with a later modification time
    os.utime(bag, ns=(os.stat(bag).st_atime_ns, os.stat(bag).st_mtime_ns + 10**9))
    with ros1.Ros1Bag(bag):
        pass
    assert len(parsed) == 2 * n


def test_a_definition_that_does_not_match_its_md5_sum_is_one_line(tmp_path):
    """rosbags' AnyReader refuses such a bag ("hash mismatch"); so does rig, in its own words."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / "wrong.bag"
    with Writer(path) as out:
        info = "sensor_msgs/msg/CameraInfo"
        c = out.add_connection("/camera/depth/camera_info", info, msgdef=ts.generate_msgdef(info)[0],
                               md5sum="0123456789abcdef0123456789abcdef")
        out.write(c, 10**9, b"")
    with pytest.raises(AnyReaderError, match="hash mismatch"):
        AnyReader([path]).open()
    with pytest.raises(FolderImportError) as e:
        read_facts(path)
    line = str(e.value)
    assert "\n" not in line and "not a readable bag" in line and "does not match its MD5 sum" in line, line
