"""Devices: which camera and stage, what they read back, and a test capture."""

from __future__ import annotations

import threading

from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.message import Message
from textual.widgets import Input, Label
from textual.worker import get_current_worker

from drivers.camera import CameraSettings
from drivers.errors import DeviceError

from protocols.plan_check import RigLimits
from protocols.region_of_interest import Region

from .devices_service import DeviceReport, DeviceSession, TestCapture, describe_error
from .fields import PasteField
from .image_widgets import DepthImage, IrImage
from .preview import WallView, frame_view, view_rows
from .widgets import KeyValues, StatusLine

#: the live preview: a frame this often (s), and how long stopping it waits for its frame at most (s)
PREVIEW_PERIOD_S = 0.2
PREVIEW_STOP_S = 2.0


class DevicesPane(Vertical):
    """Device strings, connect/disconnect/home, read-back and a test capture."""

    class Done(Message):
        """A device operation finished (in the worker); the screen shows its outcome."""

        def __init__(self, what: str, report: DeviceReport | None = None, capture: TestCapture | None = None,
                     error: str = "") -> None:
            super().__init__()
            self.what, self.report, self.capture, self.error = what, report, capture, error

    class LimitsChanged(Message):
        """What the devices allow (travel, image size) became known or unknown: the experiment form rechecks."""

    class PreviewFrame(Message):
        """A frame of the live preview, seen (posted from the preview's thread)."""

        def __init__(self, view: WallView) -> None:
            super().__init__()
            self.view = view

    def __init__(self, camera: str, stage: str, **kw) -> None:
        super().__init__(**kw)
        self.session = DeviceSession()
        self._camera, self._stage = camera, stage
        self.busy = False
        self._limits: tuple[tuple[str, str], RigLimits] | None = None
        self._stop_preview = threading.Event()  # set: the preview's thread ends after its frame
        self._preview_ended = threading.Event()
        self._preview_ended.set()

    @property
    def limits(self) -> RigLimits | None:
        """The travel and image size of the devices last connected, while their strings are unchanged."""
        if self._limits is None or self._limits[0] != (self.camera_string, self.stage_string):
            return None
        return self._limits[1]

    def compose(self) -> ComposeResult:
        with Horizontal(classes="field"):
            yield Label("Camera", classes="label")
            yield PasteField(self._camera, id="camera-string", compact=True)
        with Horizontal(classes="field"):
            yield Label("Stage", classes="label")
            yield PasteField(self._stage, id="stage-string", compact=True)
        yield StatusLine("not connected: press c to connect", id="devices-status")
        with Horizontal(classes="columns"):
            yield KeyValues(id="camera-info", classes="left")
            with Vertical(classes="right"):
                yield KeyValues(id="stage-info")
                yield KeyValues(id="capture-info")
                with Vertical(id="preview-box"):
                    yield KeyValues(id="preview-info")
                    with Horizontal(id="preview-images"):
                        yield DepthImage(id="depth-image")
                        yield IrImage(id="ir-image")

    # -- what the app asks ------------------------------------------------------------------
    @property
    def camera_string(self) -> str:
        return self.query_one("#camera-string", Input).value.strip()

    @property
    def stage_string(self) -> str:
        return self.query_one("#stage-string", Input).value.strip()

    def set_strings(self, camera: str, stage: str) -> None:
        self.query_one("#camera-string", Input).value = camera
        self.query_one("#stage-string", Input).value = stage

    @property
    def status(self) -> StatusLine:
        return self.query_one("#devices-status", StatusLine)

    def connect(self) -> None:
        self._start("connect", f"connecting {self.camera_string} and {self.stage_string} ...")

    def disconnect(self) -> None:
        self._start("disconnect", "disconnecting ...")

    def home(self) -> None:
        self._start("home", "homing the stage ...")

    def test_capture(self, settings: CameraSettings) -> None:
        self._start("capture", "capturing 10 frames ...", settings)

    # -- the live preview --------------------------------------------------------------------
    @property
    def previewing(self) -> bool:
        return not self._preview_ended.is_set()

    def start_preview(self, settings: CameraSettings, region: Region | None = None) -> None:
        """v: frames from the camera where the stage stands, five a second, with the experiment's settings: the
        depth and IR images, the fill rate, the wall's plane and the IR level (`preview.frame_view`), of the
        experiment's region of interest when it has one, until `stop_preview`."""
        self._stop_preview.clear()
        self._preview_ended.clear()
        self.query_one("#preview-box").display = True
        self.query_one("#capture-info", KeyValues).display = False
        self.status.show("live preview: v stops it", "busy")
        self._preview(settings, region)

    def stop_preview(self) -> None:
        """End the preview and wait (a frame at most) for its thread to let go of the camera."""
        self._stop_preview.set()
        self._preview_ended.wait(PREVIEW_STOP_S)
        self.query_one("#preview-box").display = False
        self.query_one("#capture-info", KeyValues).display = True

    @work(thread=True, exclusive=True, group="preview")
    def _preview(self, settings: CameraSettings, region: Region | None) -> None:
        worker = get_current_worker()
        try:
            camera = self.session.devices.camera if self.session.devices else None
            if camera is None:
                raise DeviceError("not connected: press c to connect")
            camera.configure(settings)
            info = camera.info()
            if region is not None:
                try:
                    region.check_fits(info.intrinsics.width, info.intrinsics.height)
                except ValueError as e:  # the words a run's camera refuses it with (`RegionCamera.open`)
                    raise DeviceError(f"{camera.name}: {e}") from None
            while not self._stop_preview.is_set() and not worker.is_cancelled:
                for frame in camera.frames(1, ir=True):
                    self.post_message(self.PreviewFrame(frame_view(frame, info, camera.ir_full_scale_dn, region)))
                self._stop_preview.wait(PREVIEW_PERIOD_S)
        except DeviceError as e:
            self.post_message(self.Done("preview", error=str(e)))
        except Exception as e:  # noqa: BLE001 - a driver's own bug is one line on the screen, not the end of the UI
            self.post_message(self.Done("preview", error=f"preview failed: {type(e).__name__}: {e}"))
        finally:
            self._preview_ended.set()

    def on_devices_pane_preview_frame(self, m: PreviewFrame) -> None:
        if self._stop_preview.is_set():
            return
        self.query_one("#preview-info", KeyValues).show_rows(view_rows(m.view))
        self.query_one(DepthImage).show_image(m.view.image_m, m.view.inside)
        self.query_one(IrImage).show_ir(m.view.ir, m.view.inside)

    def released(self, why: str) -> None:
        """The run takes the devices (and closes them here, in its own thread): say so."""
        self._clear()
        self.status.show(f"disconnected: {why}; press c to connect again", "info")

    # -- work -------------------------------------------------------------------------------
    def _start(self, what: str, text: str, settings: CameraSettings | None = None) -> None:
        if self.busy:
            self.status.show("busy: wait for the device operation to finish", "error")
            return
        if self.previewing:  # the operation takes the camera (or closes it)
            self.stop_preview()
        self.busy = True
        self.status.show(text, "busy")
        self.app.refresh_bindings()
        self._work(what, self.camera_string, self.stage_string, settings)

    @work(thread=True, exclusive=True, group="devices")
    def _work(self, what: str, camera: str, stage: str, settings: CameraSettings | None) -> None:
        try:
            if what == "connect":
                self.post_message(self.Done(what, report=self.session.connect(camera, stage)))
            elif what == "disconnect":
                self.session.disconnect()
                self.post_message(self.Done(what))
            elif what == "home":
                self.post_message(self.Done(what, report=self.session.home()))
            elif what == "capture":
                assert settings is not None
                capture = self.session.test_capture(settings)
                self.post_message(self.Done(what, report=self.session.report(), capture=capture))
        except DeviceError as e:
            self.post_message(self.Done(what, error=describe_error(e) if what == "connect" else str(e)))
        except Exception as e:  # noqa: BLE001 - a driver's own bug is one line on the screen, not the end of the UI
            self.post_message(self.Done(what, error=f"{what} failed: {type(e).__name__}: {e}"))

    def on_devices_pane_done(self, m: Done) -> None:
        if m.what == "preview":  # (its thread ended on an error; it was never `busy`)
            self.stop_preview()
            self.status.show(m.error, "error")
            self.app.refresh_bindings()
            return
        self.busy = False
        self.app.refresh_bindings()
        if m.error:
            if m.what == "connect":
                self._clear()
            self.status.show(m.error, "error")
            return
        if m.what == "disconnect":
            self._clear()
            self.status.show("disconnected; press c to connect", "info")
            return
        if m.report is not None:
            self.query_one("#camera-info", KeyValues).show_rows(m.report.camera, "camera")
            self.query_one("#stage-info", KeyValues).show_rows(m.report.stage, "stage")
            if m.report.limits is not None and m.what == "connect":
                self._limits = ((self.session.camera_text, self.session.stage_text), m.report.limits)
                self.post_message(self.LimitsChanged())
        if m.what == "connect":
            self.status.show(f"connected: {self.session.camera_text} and {self.session.stage_text}", "ok")
        elif m.what == "home":
            self.status.show("stage homed", "ok")
        elif m.what == "capture" and m.capture is not None:
            c = m.capture
            self.query_one("#capture-info", KeyValues).show_rows([
                ("frames", str(c.frames)), ("fill rate", f"{100 * c.fill_rate:.1f} %"),
                ("range centre", f"{c.centre_mean_m:.4f} m"), ("sigma centre", f"{1000 * c.centre_sigma_m:.3f} mm"),
            ], "test capture")
            self.status.show(f"test capture: fill {100 * c.fill_rate:.1f} %, centre {c.centre_mean_m:.3f} m", "ok")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.connect()

    def on_input_changed(self, event: Input.Changed) -> None:
        event.stop()
        self.post_message(self.LimitsChanged())  # other devices: their travel is not known until connected

    def _clear(self) -> None:
        for wid in ("#camera-info", "#stage-info", "#capture-info"):
            self.query_one(wid, KeyValues).show_rows([])
