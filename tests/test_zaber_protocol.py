"""The Zaber simulator against the official client library, and the Zaber driver against a device as it
really behaves: checksums, message ids, resolution, identity, every warning flag.

`zaber-motion` (Zaber's own library, a test dependency) is the independent judge: it computes and checks
checksums and message ids itself. It cannot identify the device here (identification asks Zaber's online
device database, which CI cannot reach), so it runs with `identify_devices=False`, in native units.
"""

from __future__ import annotations

import threading
import time

import pytest
from zaber_motion import Units
from zaber_motion.ascii import Connection

from drivers.errors import StageError
from drivers.serial import ZaberStage
from drivers.serial.zaber import checksum as driver_checksum
from fakes.zaber_sim import ZaberSim, checksum as sim_checksum

pytestmark = pytest.mark.slow


FAST = {"speed_mm_s": 5000.0, "start_mm": 100.0, "travel_mm": 3000.0}


def stage_for(sim: ZaberSim, **options) -> ZaberStage:
    """A driver for `sim`, opened by `with` (or `.open()`)."""
    return ZaberStage(sim.port, offset_m=0.3, settle_s=0.0, poll_s=0.01, **options)


def test_checksum_matches_the_manuals_worked_example():
    # the rule (Zaber ASCII protocol manual, "Checksums"): the byte sum of the message plus its checksum is 0 mod 256
    body = "1 1 move abs 10000"
    total = sum(body.encode("ascii"))
    assert (total + int(sim_checksum(body), 16)) % 256 == 0
    assert sim_checksum(body) == driver_checksum(body)
    # the first message zaber-motion sends to find devices is '/0 0 00:00' (seen on the wire)
    assert sim_checksum("0 0 00") == "00"


def test_official_library_detects_homes_moves_and_reads_with_checksums():
    with ZaberSim(**FAST) as sim, Connection.open_serial_port(sim.port) as conn:
        assert conn.checksum_enabled  # the library's default: every command carries a checksum
        alerts: list = []
        conn.alert.subscribe(alerts.append)
        devices = conn.detect_devices(identify_devices=False)
        assert [d.device_address for d in devices] == [1]
        device = devices[0]
        device.generic_command("set comm.checksum 1")  # the device now checksums its replies too
        device.generic_command("set comm.alert 1")
        axis = device.get_axis(1)
        axis.home()
        axis.move_absolute(1_000_000, Units.NATIVE)
        axis.move_relative(-250_000, Units.NATIVE)
        assert axis.get_position(Units.NATIVE) == 750_000
        carriage_mm = sim.carriage.position_mm(time.monotonic())
        assert carriage_mm == pytest.approx(750_000 * sim.microstep_um / 1000.0 + sim.origin_mm, abs=1e-6)
        assert axis.settings.get("resolution") == 64
        assert int(device.generic_command("get deviceid").data) == sim.device_id
        assert axis.warnings.get_flags() == set()
        deadline = time.monotonic() + 5.0  # the library hands alerts over on its own thread: wait for them
        while len(alerts) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        # home and both moves ended
        assert len(alerts) >= 3 and all(a.status == "IDLE" for a in alerts), f"within 5 s, alerts {alerts}, not 3 IDLE"
        # every command it sent carried a message id and a valid checksum
        framed = [c for c in sim.commands if c.startswith("/")]
        assert framed and all(":" in c and sim_checksum(c[1:c.rindex(":")]) == c[c.rindex(":") + 1:] for c in framed)
        assert all(len(c[1:].split()) >= 3 for c in framed)


class _BadChecksumSim(ZaberSim):
    """A device whose reply checksums are off by one: the library must refuse them (a negative control)."""

    def send_message(self, text: str) -> None:
        good = int(sim_checksum(text[1:]), 16)
        self.send_line(f"{text}:{(good + 1) % 256:02X}")


def test_official_library_refuses_a_wrong_reply_checksum():
    # the control for the test above: if the library ignored reply checksums, accepting ours would prove nothing
    with _BadChecksumSim(**FAST) as sim, Connection.open_serial_port(sim.port) as conn:
        with pytest.raises(Exception, match="(?i)checksum|cannot find any device"):
            conn.detect_devices(identify_devices=False)


def test_simulator_drops_a_message_with_a_wrong_checksum_and_echoes_message_ids():
    with ZaberSim(**FAST) as sim, stage_for(sim) as stage:
        n = len(sim.replies)
        stage.link.write(b"/1 1 42 get pos:00\n", "a corrupted command")
        stage.link.write(f"/1 1 43 get pos:{sim_checksum('1 1 43 get pos')}\n".encode(), "a good command")
        time.sleep(0.2)
        new = sim.replies[n:]
        assert len(new) == 1 and new[0].startswith("@01 1 43 OK ")


def test_driver_sends_ids_and_checksums_and_checks_replies_checksums():
    with ZaberSim(**FAST) as sim, stage_for(sim) as stage:
        sim.checksums = True
        stage.home()
        assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-6)
        sent = [c for c in sim.commands if c.startswith("/1 ")]
        assert all(sim_checksum(c[1:c.rindex(":")]) == c[-2:] for c in sent)
        ids = [int(c.split()[2]) for c in sent if c.split()[2].isdigit()]
        assert len(ids) == len(sent) and len(set(ids[:99])) == min(len(ids), 99)


def test_driver_refuses_a_reply_whose_checksum_is_wrong():
    with _BadChecksumSim(**FAST) as sim, pytest.raises(StageError, match=r"garbled reply .*baud"):
        stage_for(sim).open()


def test_driver_reads_the_resolution_so_a_changed_resolution_does_not_scale_the_distances():
    # the datasheet's microstep (0.1905 um) is at resolution 64; this stage was set to 128
    with ZaberSim(**FAST, resolution=128) as sim, stage_for(sim, microstep_um=0.1905) as stage:
        assert stage.microstep_um == pytest.approx(0.1905 / 2)
        stage.home()
        stage.move_to(1.0)
        assert sim.carriage.position_mm(time.monotonic()) == pytest.approx(700.0, abs=1e-3)
        assert stage.describe()["device_resolution"] == "128"
        assert stage.describe()["device_deviceid"] == str(sim.device_id)


def test_driver_checks_the_device_id_the_device_string_pins():
    with ZaberSim(**FAST, device_id=50081) as sim:
        with pytest.raises(StageError) as err:
            stage_for(sim, device_id=50419).open()
        assert "is deviceid 50081" in str(err.value) and "not deviceid 50419" in str(err.value)
        assert "\n" not in str(err.value)
        with stage_for(sim, device_id=50081) as stage:
            assert stage.identity["system.serial"] == str(sim.serial)


def test_driver_sees_a_flag_hidden_behind_a_more_urgent_one():
    # a temperature warning (WT) outranks 'movement interrupted' (NI), so replies show only WT;
    # the driver must read `warnings` and stop on NI
    with ZaberSim(speed_mm_s=200.0, start_mm=100.0) as sim, stage_for(sim) as stage:
        stage.home()

        def interrupt() -> None:
            time.sleep(0.3)
            with sim._lock:
                sim.flags |= {"WT", "NI"}
        threading.Thread(target=interrupt, daemon=True).start()
        with pytest.raises(StageError, match=r"movement interrupted \(NI\)"):
            stage.move_to(2.0)
        assert any(c.split(":")[0].endswith("warnings") for c in sim.commands)
