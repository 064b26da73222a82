"""`rig sigma-bag`: a recorded bag copied with a sigma image beside each depth frame, for a ROS pipeline to weight
depth by (docs/noise-model.md).

drivers.bag.contents finds the bag's depth topic and says its depth unit, and drivers.bag.depth_messages decodes each
frame in any form the import reads (16UC1 or 32FC1, either byte order, raw or compressedDepth png/rvl);
the messages are then read and written with rosbags: every topic of the input, message for message (the same bytes
at the same times), into a bag of the same kind (ROS 1 `.bag`; a ROS 2 bag folder with the input's storage, sqlite3
or MCAP), and one topic more, `<depth topic>/sigma` unless named: a sensor_msgs/Image, 32FC1 little-endian (REP 118:
float depth images are in metres), the model's sigma in m at each pixel of each depth frame, under the depth frame's
own header (stamp and frame_id; seq in ROS 1). sigma is evaluated at the measured depth as the range (a sample's
error is small beside its range) and at the pixel's column and row; NaN where the depth is 0 (no data). A model whose
terms need a measured input per pixel is refused as for a sigma map (`rig.reports.sigma_map.map_problem`).

The bag is written under a temporary name in the output's folder and renamed when complete: a failure or an
interrupt leaves no output, and no bag that looks whole but is not.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError, Writer as Ros1Writer, WriterError
from rosbags.rosbag2 import ReaderError as Reader2Error, StoragePlugin, Writer as Ros2Writer
from rosbags.rosbag2 import WriterError as Writer2Error
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from drivers.bag import read_facts
from drivers.bag.depth_messages import COMPRESSED_IMAGE, DepthMessageError, decode, depth_format

from ..noise_model import NoiseModel
from .sigma_map import map_problem

IMAGE = "sensor_msgs/msg/Image"
#: the encoding of the sigma images: one float32 a pixel, metres (REP 118)
SIGMA_ENCODING = "32FC1"


class SigmaBagError(ValueError):
    """A bag, model or output this command cannot use: one line naming the problem and the fix."""


@dataclass(frozen=True)
class SigmaBag:
    """What `write_sigma_bag` wrote."""

    path: Path
    depth_topic: str
    sigma_topic: str
    frames: int
    depth_unit_m: float
    notes: tuple[str, ...] = ()  # what the user should know: the bag's camera is not the model's


def bag_kind(bag: Path) -> str:
    """"ros1", "sqlite3" or "mcap": the kind of bag `bag` is, and the kind written."""
    if bag.suffix.lower() == ".bag":
        return "ros1"
    if bag.suffix.lower() == ".mcap" or (bag.is_dir() and any(bag.glob("*.mcap"))):
        return "mcap"
    return "sqlite3"


def default_output(bag: Path) -> Path:
    """BAG-sigma.bag for a ROS 1 bag, the folder BAG-sigma for a ROS 2 one."""
    stem = bag.name if bag.is_dir() else bag.stem
    return bag.with_name(f"{stem}-sigma.bag" if bag_kind(bag) == "ros1" else f"{stem}-sigma")


def output_problem(bag: Path, out: Path) -> str | None:
    """Why `out` cannot take the copy of `bag`, or None."""
    if out.exists():
        return f"{out} exists; remove it or give another -o"
    ros1 = bag_kind(bag) == "ros1"
    if ros1 and out.suffix.lower() != ".bag":
        return f"{bag} is a ROS 1 bag, so the copy is one too: give -o a name ending in .bag"
    if not ros1 and out.suffix.lower() in (".bag", ".db3", ".mcap"):
        return f"{bag} is a ROS 2 bag, so the copy is a ROS 2 bag folder: give -o a folder name without {out.suffix}"
    return None


def pixel_grid(model: NoiseModel) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """u (column) and v (row) of every pixel of the model's depth image, and the inputs a wall perpendicular to the
    axis gives the terms (cos_incidence = 1 / sqrt(1 + rho^2), as for the sigma map)."""
    k = model.doc["camera"]["intrinsics"]
    v, u = np.mgrid[0:k["height"], 0:k["width"]].astype(float)
    rho2 = ((u - k["cx"]) / k["fx"]) ** 2 + ((v - k["cy"]) / k["fy"]) ** 2
    return u, v, ({"cos_incidence": 1.0 / np.sqrt(1.0 + rho2)} if "cos_incidence" in model.inputs else {})


def sigma_image(model: NoiseModel, depth: np.ndarray, depth_unit_m: float,
                grid: tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]) -> np.ndarray:
    """sigma, m, float32, of each pixel of a depth image (counts; 0 = no data, NaN there), its range z = counts x
    depth_unit_m (docs/noise-model.md, "The formula of every term")."""
    u, v, extra = grid
    valid = depth > 0
    out = np.full(depth.shape, np.nan, dtype=np.float32)
    z = depth[valid].astype(float) * depth_unit_m
    out[valid] = model.sigma(z, u[valid], v[valid], **{n: a[valid] for n, a in extra.items()})
    return out


def write_sigma_bag(model: NoiseModel, bag: Path, out: Path, *, topic: str | None = None,
                    sigma_topic: str | None = None) -> SigmaBag:
    """Copy `bag` to `out` with a sigma topic (module docstring); SigmaBagError, or drivers' FolderImportError for a
    bag it cannot read, with nothing written."""
    problem = map_problem(model.inputs)
    if problem:
        raise SigmaBagError(problem)
    problem = output_problem(bag, out)
    if problem:
        raise SigmaBagError(problem)
    facts = read_facts(bag, topic)  # the depth topic, checked; FolderImportError (one line) if none
    k = model.doc["camera"]["intrinsics"]
    if (facts.width, facts.height) != (k["width"], k["height"]):
        raise SigmaBagError(f"{bag}: {facts.topic} is {facts.width}x{facts.height} px, the model's camera "
                            f"{k['width']}x{k['height']} px; export a model fitted at this camera's resolution")
    notes = camera_notes(model.doc["camera"], facts.fx, facts.baseline_m, bag)
    unit = facts.depth_unit_m if np.isfinite(facts.depth_unit_m) else float(model.doc["camera"]["depth_unit_m"])
    sigma_topic = sigma_topic or f"{facts.topic}/sigma"
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        frames = _copy(model, bag, partial / out.name, facts.topic, sigma_topic, unit, bag_kind(bag))
        os.rename(partial / out.name, out)
    except (AnyReaderError, ReaderError, WriterError, Reader2Error, Writer2Error, SerdeError) as e:
        raise SigmaBagError(f"{bag}: cannot copy it ({type(e).__name__}: {' '.join(str(e).split())}); nothing was "
                            "written; give a readable RealSense .bag or ROS 1/ROS 2 bag") from None
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return SigmaBag(out, facts.topic, sigma_topic, frames, unit, notes)


#: a focal length or baseline this far (relatively) from the model's is another camera's: units of one model differ
#: by about 1 % in their factory calibration
OTHER_CAMERA = 0.05


def camera_notes(camera: dict, fx_px: float, baseline_m: float, bag: Path) -> tuple[str, ...]:
    """A note when the bag's camera (its fx and baseline, where the bag says them) is not the model's: sigma scales
    as 1 / (f b) (docs/noise-model.md), so the model's sigma is not this camera's."""
    ours = {"fx": (fx_px, camera["intrinsics"]["fx"], "px", 1.0), "baseline": (baseline_m, camera["baseline_m"], "mm", 1e3)}
    off = [f"{name} {v * k:.4g} {unit} against the model's {m * k:.4g} {unit}" for name, (v, m, unit, k) in ours.items()
           if np.isfinite(v) and m and abs(v - m) > OTHER_CAMERA * abs(m)]
    if not off:
        return ()
    return (f"{bag}'s camera is not the model's ({'; '.join(off)}): its sigma scales as 1 / (f b), so these sigma "
            "images are not this camera's; export a model fitted to this camera (rig import, rig export)",)


def _copy(model: NoiseModel, bag: Path, target: Path, depth_topic: str, sigma_topic: str, unit: float,
          kind: str) -> int:
    grid = pixel_grid(model)
    h, w = grid[0].shape
    reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))  # the store: for a bag without
    with reader, _writer(target, kind) as writer:  # its messages' definitions (rosbags' AnyReader)
        if any(c.topic == sigma_topic for c in reader.connections):
            raise SigmaBagError(f"{bag} has a topic {sigma_topic} already; name another with --sigma-topic")
        copies = {c.id: _connection(writer, reader, c, c.topic, kind) for c in reader.connections}
        depth = [c for c in reader.connections if c.topic == depth_topic and c.msgtype in (IMAGE, COMPRESSED_IMAGE)]
        store = reader.typestore if IMAGE in reader.typestore.types else get_typestore(
            Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)  # a bag of compressed depth alone
        sigma_c = (_connection(writer, reader, depth[0], sigma_topic, kind) if depth[0].msgtype == IMAGE
                   else _image_connection(writer, store, depth[0], sigma_topic, kind))
        Image = store.types[IMAGE]
        serialize = store.serialize_ros1 if kind == "ros1" else store.serialize_cdr
        frames = 0
        first = None
        for c, t, raw in reader.messages():
            writer.write(copies[c.id], t, raw)
            if c.topic != depth_topic or c.msgtype not in (IMAGE, COMPRESSED_IMAGE):
                continue
            msg = reader.deserialize(raw, c.msgtype)
            frames += 1
            try:
                fmt = depth_format(msg, c.msgtype, depth_topic)
                image = decode(msg, fmt)
            except DepthMessageError as e:
                raise SigmaBagError(f"{bag}: frame {frames} of {depth_topic}: {e}; nothing was written") from None
            first = first or (fmt, image.shape)
            if (fmt, image.shape) != first or image.shape != (h, w):
                raise SigmaBagError(f"{bag}: frame {frames} of {depth_topic} is {image.shape[1]}x{image.shape[0]} {fmt}, "
                                    f"the first {first[1][1]}x{first[1][0]} {first[0]} and the model's camera {w}x{h}; "
                                    "give a bag of one depth stream at the model's resolution")
            # depth in metres (32FC1) is evaluated as it is, counts at the depth unit
            z_unit = 1.0 if fmt.metres else unit
            sigma = sigma_image(model, np.where(np.isfinite(image), image, 0), z_unit, grid)
            data = sigma.astype("<f4").view(np.uint8).ravel()
            out = Image(header=msg.header, height=h, width=w, encoding=SIGMA_ENCODING, is_bigendian=0, step=4 * w,
                        data=data)
            writer.write(sigma_c, t, serialize(out, IMAGE))
    return frames


def _writer(target: Path, kind: str) -> Any:
    if kind == "ros1":
        return Ros1Writer(target)
    return Ros2Writer(target, version=8, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)


def _connection(writer: Any, reader: Any, c: Any, topic: str, kind: str) -> Any:
    """A connection of the writer like the reader's `c` (its type's definition and hash, its QoS or caller), on
    `topic`; one the writer has already is reused."""
    definition = c.msgdef.data if c.msgdef is not None and c.msgdef.data else None
    for have in writer.connections:
        if have.topic == topic and have.msgtype == c.msgtype and have.ext == c.ext:
            return have
    if kind == "ros1":
        return writer.add_connection(topic, c.msgtype, typestore=None if definition and c.digest else reader.typestore,
                                     msgdef=definition, md5sum=c.digest or None, callerid=c.ext.callerid,
                                     latching=c.ext.latching)
    return writer.add_connection(topic, c.msgtype, typestore=None if definition and c.digest else reader.typestore,
                                 msgdef=definition, rihs01=c.digest or None,
                                 serialization_format=c.ext.serialization_format,
                                 offered_qos_profiles=c.ext.offered_qos_profiles)


def _image_connection(writer: Any, store: Any, c: Any, topic: str, kind: str) -> Any:
    """An Image connection on `topic`, from `store`'s definition, with `c`'s caller or QoS (its depth topic's)."""
    if kind == "ros1":
        return writer.add_connection(topic, IMAGE, typestore=store, callerid=c.ext.callerid, latching=c.ext.latching)
    return writer.add_connection(topic, IMAGE, typestore=store, serialization_format=c.ext.serialization_format,
                                 offered_qos_profiles=c.ext.offered_qos_profiles)
