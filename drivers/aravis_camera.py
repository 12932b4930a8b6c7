"""GenICam camera (GigE Vision, USB3 Vision) through Aravis 0.8 and PyGObject.

Protocol facts, settings and pitfalls: docs/drivers/aravis.md.

- The camera is found by its Aravis device id (``"Vendor-Serial"``, or an IP address
  for a GigE camera) or by its serial number (looked up in Aravis's device list).
- Feature names that differ between cameras (``ExposureTime`` / ``ExposureTimeAbs``,
  ``Gain`` (dB) / ``GainRaw``, ``AcquisitionFrameRate`` / ``...Abs``) are resolved
  once at open; Aravis's range checking is switched on (0.8 leaves it off).
- Automatic exposure and gain (``ExposureAuto``, ``GainAuto``, where the camera has
  them) are switched off at open and read back: a camera that powers up in continuous
  auto exposure (FLIR Blackfly S) would otherwise override the exposure written.
- Pixel formats: mono8, mono10 (Mono10, packed Mono10p), mono12 (Mono12, Mono12p,
  Mono16), mono16; a colour camera's Bayer mosaic (BayerRG8/GR8/GB8/BG8 and the 16-bit
  ones) demosaiced to rgb8/rgb16 on the host, or delivered raw as bayer8/bayer16
  (pattern in ``info["bayer_pattern"]``); RGB8 cameras as rgb8.
- The hardware ROI is the smallest region on the camera's increments that covers
  the requested one; the host unpacks, demosaics, crops to the exact ROI, bins (block
  average) and converts the pixel format (:mod:`drivers.camera_image`).
- Frames arrive through one stream with a pool of ``n_buffers`` buffers; every
  popped buffer is pushed back (also when its frame is dropped). A buffer whose
  status is not SUCCESS (missing packets, size mismatch, ...) is counted as dropped
  and never delivered; a gap in the camera's frame ids counts the frames in it as
  dropped. Frame indices count from 0 at open, dropped frames included.
- Free-run rate: the camera runs at ``min(frame_rate_hz, 1 / exposure_s)`` (the
  driver writes that rate, so a long exposure lowers it on every camera alike).
- A lost camera (GigE heartbeat ``control-lost``, or no answer to a probe after a
  second without frames: :func:`drivers.aravis_support.gvcp_answers` for GigE) ends
  the stream with :class:`~drivers.errors.DeviceDisconnectedError`;
  :meth:`Device.reconnect` opens it again by id and re-applies the settings.

Every wait has a timeout: frames are popped with a deadline, the GigE probe waits
0.6 s, Aravis's own register access times out inside Aravis (2.5 s per read).
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Any

from drivers.aravis_support import (
    FORMATS,
    LOST_CODES,
    decode,
    frames_between,
    gvcp_answers,
    import_aravis,
)
from drivers.camera import Camera, Frame, FrameRing
from drivers.camera_image import aligned_region, frame_image
from drivers.errors import (
    DeviceDisconnectedError,
    DeviceError,
    DeviceValueError,
)
from drivers.grab_thread import GrabStream

__all__ = ["AravisCamera"]

class AravisCamera(GrabStream, Camera):
    """A GenICam camera driven through Aravis.

    Parameters
    ----------
    device_id : str
        Name of the device.
    camera_name : str, optional
        Aravis device id (``"Allied Vision-1AB22C00F8A1"``, as ``arv-tool-0.8`` lists
        it) or a GigE camera's IP address.
    serial_number : str, optional
        The camera's serial number (used when ``camera_name`` is not given).
    pixel_format : str, optional
        "mono8", "mono10", "mono12", "mono16", "rgb8", "rgb16", "bayer8" or "bayer16",
        set at open (default: the camera's current one, else the first monochrome one
        it has, else rgb8).
    exposure_s, gain, frame_rate_hz : float, optional
        Exposure (s), gain (dB) and free-run rate (Hz) set at open.
    trigger_line : str
        Input line of the "hardware" trigger mode (GenICam ``TriggerSource``).
    packet_size : int, optional
        GigE Vision stream packet size in bytes (``GevSCPSPacketSize``; 8228 for jumbo
        frames). Ignored for USB3 cameras.
    n_buffers : int
        Buffers in the stream's pool (>= 2).
    pixel_pitch_um : float, optional
        Sensor pixel pitch; default the camera's ``SensorPixelWidth`` feature.
    gain_db_per_raw : float, optional
        dB per unit of ``GainRaw``, for cameras without a ``Gain`` (dB) feature (from
        the camera's manual). Without it such a camera's gain stays at its current value.
    fake_interface : bool
        Enable libaravis's in-process fake camera (device id ``"Fake_1"``; tests).
    frame_retention_s : float
        GigE: how long a frame may stay incomplete before it is dropped (Aravis's
        ``frame-retention``, 0.1 s by default, which a busy host can exceed while the
        missing packets are still waiting in the socket buffer).

    Raises
    ------
    DeviceValueError
        A parameter is invalid (nothing is opened by the constructor).
    """

    def __init__(
        self, device_id: str, *, camera_name: str | None = None,
        serial_number: str | None = None, pixel_format: str | None = None,
        exposure_s: float | None = None, gain: float | None = None,
        frame_rate_hz: float | None = None, trigger_line: str = "Line0",
        packet_size: int | None = None, n_buffers: int = 8,
        pixel_pitch_um: float | None = None, gain_db_per_raw: float | None = None,
        fake_interface: bool = False, frame_retention_s: float = 0.5,
    ) -> None:
        super().__init__(device_id)
        if not camera_name and not serial_number:
            raise self._error(
                DeviceValueError, "neither camera_name nor serial_number is given",
                "set params.camera_name to the Aravis device id (arv-tool-0.8 lists it) "
                "or params.serial_number",
            )
        for name, value in (("camera_name", camera_name), ("serial_number", serial_number),
                            ("trigger_line", trigger_line)):
            if value is not None and (not isinstance(value, str) or not value.strip()):
                raise self._error(DeviceValueError, f"{name}={value!r} is not a name",
                                  f"give {name} as a non-empty string")
        if pixel_format is not None:
            self._choice("pixel_format", pixel_format, list(FORMATS))
        self._initial = {
            k: v for k, v in (("pixel_format", pixel_format), ("exposure_s", exposure_s),
                              ("frame_rate_hz", frame_rate_hz), ("gain", gain))
            if v is not None
        }
        for k in ("exposure_s", "frame_rate_hz"):
            if k in self._initial:
                self._float(k, self._initial[k], low=0.0, low_open=True)
        if "gain" in self._initial:
            self._float("gain", gain, low=0.0)
        self._name, self._serial = camera_name, serial_number
        self._line = trigger_line
        self._packet = None if packet_size is None else self._int(
            "packet_size", packet_size, low=576, high=16384)
        self._n_buffers = self._int("n_buffers", n_buffers, low=2, high=256)
        self._pitch = None if pixel_pitch_um is None else self._float(
            "pixel_pitch_um", pixel_pitch_um, low=0.0, low_open=True)
        self._db_per_raw = None if gain_db_per_raw is None else self._float(
            "gain_db_per_raw", gain_db_per_raw, low=0.0, low_open=True)
        self._fake = bool(fake_interface)
        self._retention_s = self._float("frame_retention_s", frame_retention_s, low=0.001,
                                        high=60.0)
        self._gige = False
        self._arv: Any = None
        self._glib: Any = None
        self._cam: Any = None
        self._stream: Any = None
        self._pool_payload = 0
        self._payload = 0
        self._features: dict[str, str | None] = {}
        self._hw: dict[str, Any] = {}
        self._lost = threading.Event()
        self._lost_handler: Any = None
        self._index = 0
        self._stats: dict[str, int] = {}
        self._gige_ip: str | None = None
        self._auto_off: list[str] = []

    # ------------------------------------------------------------------ open / close
    def _do_open(self, timeout_s: float) -> None:
        try:
            self._connect(timeout_s)
        except BaseException:
            self._do_close()  # release the camera if the open failed half-way
            raise

    def _connect(self, timeout_s: float) -> None:
        self._arv, self._glib = import_aravis(self.device_id)
        arv = self._arv
        if self._fake:
            arv.enable_interface("Fake")
        target = self._name or self._find_by_serial()
        try:
            cam = arv.Camera.new(target)
        except self._glib.Error as exc:
            raise self._error(
                DeviceDisconnectedError, f"camera {target!r} not found ({exc.message})",
                "check cable, power and (GigE) the network; arv-tool-0.8 lists the cameras "
                "Aravis sees",
            ) from exc
        self._cam, self._stream, self._pool_payload = cam, None, 0
        self._lost.clear()
        self._lost_handler = cam.get_device().connect("control-lost", self._on_control_lost)
        self._index = 0
        self._stats = {"completed": 0, "incomplete": 0, "id_gaps": 0}
        self._call(cam.set_range_check_policy, arv.RangeCheckPolicy.ENABLE)
        self._resolve_features()
        self._automatic_off()
        self._gige_ip = None
        self._gige = bool(cam.is_gv_device())
        if self._gige:  # the fast liveness probe, if this camera answers it
            ip = cam.get_device().get_device_address().get_address().to_string()
            self._gige_ip = ip if gvcp_answers(ip) else None
        if self._packet is not None and cam.is_gv_device():
            self._call(cam.gv_set_packet_size, self._packet)
        self._read_hardware()
        for name in ("pixel_format", "exposure_s", "frame_rate_hz", "gain"):
            if name in self._initial:
                self._do_apply(name, self._validate_setting(name, self._initial[name], self._hw))

    def _find_by_serial(self) -> str:
        arv = self._arv
        arv.update_device_list()
        found = []
        for i in range(arv.get_n_devices()):
            found.append(f"{arv.get_device_id(i)} (serial {arv.get_device_serial_nbr(i)})")
            if arv.get_device_serial_nbr(i) == self._serial:
                return arv.get_device_id(i)
        raise self._error(
            DeviceDisconnectedError, f"no camera with serial number {self._serial!r}; "
            f"Aravis sees: {', '.join(found) or 'none'}",
            "check cable, power and the serial number (arv-tool-0.8 lists the cameras)",
        )

    def _on_control_lost(self, *_: Any) -> None:  # called from Aravis's heartbeat thread
        self._lost.set()
        self._log.error("%s: Aravis reports the control of the camera lost", self.device_id)

    def _do_close(self) -> None:
        self._stop_grab()
        cam = self._cam
        if cam is not None and not self._lost.is_set():
            with contextlib.suppress(Exception):
                cam.stop_acquisition()
        if cam is not None and self._lost_handler is not None:
            with contextlib.suppress(Exception):
                cam.get_device().disconnect(self._lost_handler)
        if cam is not None and not self._lost.is_set() and cam.is_gv_device():
            # give the GigE control channel back now, not when Python frees the object
            # (a traceback holding a reference would keep the camera locked)
            with contextlib.suppress(Exception):
                cam.get_device().leave_control()
        self._cam, self._stream, self._lost_handler = None, None, None

    def _do_check_connection(self) -> None:
        if self._lost.is_set():
            raise self._lost_error("Aravis lost the control of the camera (heartbeat)")

    def _lost_error(self, problem: str) -> DeviceDisconnectedError:
        return self._error(DeviceDisconnectedError, problem,
                           "check cable, power and network, then call reconnect()")

    def _call(self, fn: Any, *args: Any, what: str | None = None) -> Any:
        """Call an Aravis function; GLib errors become DeviceDisconnectedError (camera
        gone) or DeviceError naming the call."""
        try:
            return fn(*args)
        except self._glib.Error as exc:
            label = what or getattr(fn, "__name__", "aravis call")
            if self._lost.is_set() or (
                exc.domain == "arv-device-error-quark" and exc.code in LOST_CODES
            ):
                self._lost.set()
                raise self._lost_error(f"{label} failed: {exc.message}") from exc
            raise self._error(DeviceError, f"{label} failed: {exc.message}",
                              "check the camera's features with arv-tool-0.8 features") from exc

    # ------------------------------------------------------------------ features
    def _resolve_features(self) -> None:
        cam = self._cam

        def first(*names: str) -> str | None:
            return next((n for n in names if cam.is_feature_available(n)), None)

        f = {
            "exposure": first("ExposureTime", "ExposureTimeAbs"),
            "gain": first("Gain", "GainRaw"),
            "rate": first("AcquisitionFrameRate", "AcquisitionFrameRateAbs"),
            "rate_enable": first("AcquisitionFrameRateEnable"),
            "resulting_rate": first("AcquisitionResultingFrameRate", "ResultingFrameRate"),
            "pitch": first("SensorPixelWidth"),
        }
        if f["exposure"] is None:
            raise self._error(DeviceError, "the camera has neither ExposureTime nor "
                              "ExposureTimeAbs", "use a camera with exposure control")
        self._features = f
        formats = set(cam.dup_available_pixel_formats_as_strings() or [])
        self._formats = {ours: next((c for c in cands if c.name in formats), None)
                         for ours, cands in FORMATS.items()}
        if not any(self._formats.values()):
            raise self._error(DeviceError, f"no pixel format this driver reads among "
                              f"{sorted(formats)}", "use a camera with Mono8/10/12/16 "
                              "(or packed Mono10p/Mono12p), Bayer 8/16 or RGB8")
        self._sources = list(cam.dup_available_trigger_sources() or [])
        self._gain_is_raw = f["gain"] == "GainRaw"

    def _automatic_off(self) -> None:
        """Switch ExposureAuto and GainAuto off where the camera has them, and read back."""
        cam = self._cam
        self._auto_off = []
        for name in ("ExposureAuto", "GainAuto"):
            if not cam.is_feature_available(name):
                continue
            if self._call(cam.get_string, name) != "Off":
                self._call(cam.set_string, name, "Off", what=f"switching {name} off")
                got = self._call(cam.get_string, name)
                if got != "Off":
                    raise self._error(DeviceError, f"{name} reads {got!r} after it was "
                                      "switched off", f"switch {name} off in the camera's "
                                      "own tool, or choose another camera")
            self._auto_off.append(name)

    def _read_float(self, name: str) -> float:
        node = self._cam.get_device().get_feature(name)
        if isinstance(node, self._arv.GcFloat):
            return float(self._call(self._cam.get_float, name))
        return float(self._call(self._cam.get_integer, name))

    def _write_number(self, name: str, value: float) -> None:
        node = self._cam.get_device().get_feature(name)
        if isinstance(node, self._arv.GcFloat):
            self._call(self._cam.set_float, name, float(value), what=f"setting {name}")
        else:
            self._call(self._cam.set_integer, name, int(round(value)), what=f"setting {name}")

    def _bounds(self, name: str) -> tuple[float, float]:
        node = self._cam.get_device().get_feature(name)
        if isinstance(node, self._arv.GcFloat):
            b = self._call(self._cam.get_float_bounds, name)
        else:
            b = self._call(self._cam.get_integer_bounds, name)
        return float(b.min), float(b.max)

    def _read_hardware(self) -> None:
        """Read the camera's fixed properties and current settings into _info/_hw."""
        cam, f = self._cam, self._features
        size = self._call(cam.get_sensor_size)
        sensor = (int(size.height), int(size.width))
        incs = tuple(int(self._call(g)) for g in (
            cam.get_x_offset_increment, cam.get_y_offset_increment,
            cam.get_width_increment, cam.get_height_increment))
        wb, hb = self._call(cam.get_width_bounds), self._call(cam.get_height_bounds)
        pitch = self._pitch
        if pitch is None and f["pitch"]:
            pitch = self._read_float(f["pitch"])
        if not pitch or pitch <= 0:
            raise self._error(DeviceValueError, "the camera does not report its pixel pitch",
                              "set params.pixel_pitch_um (e.g. 3.45 for a Sony IMX264)")
        lo, hi = self._bounds(f["exposure"])
        rate_range = self._bounds(f["rate"]) if f["rate"] else (1e-3, 1e6)
        if f["gain"] and not self._gain_is_raw:
            g_lo, g_hi = self._bounds(f["gain"])
            gain_max = g_hi - max(g_lo, 0.0)
        elif f["gain"] and self._db_per_raw:
            g_lo, g_hi = self._bounds(f["gain"])
            gain_max = (g_hi - g_lo) * self._db_per_raw
        else:
            g_lo, gain_max = 0.0, 0.0
        self._gain_offset = max(g_lo, 0.0) if not self._gain_is_raw else g_lo
        self._grid = {"sensor": sensor, "increments": incs,
                      "minimum": (int(wb.min), int(hb.min))}
        self._info_cache = {
            "sensor_shape": sensor, "pixel_pitch_um": float(pitch),
            "exposure_range_s": (lo * 1e-6, hi * 1e-6), "frame_rate_range_hz": rate_range,
            "gain_range_db": (0.0, float(gain_max)),
            "pixel_formats": [k for k, v in self._formats.items() if v],
            "bayer_pattern": next((v.name[5:7] for v in self._formats.values()
                                   if v and v.layout.startswith("bayer")), None),
            "automatic_off": list(self._auto_off),
            "max_binning": 16,
            "vendor": cam.get_vendor_name(), "model": cam.get_model_name(),
            "serial_number": cam.get_device_serial_number(),
            "camera_device_id": cam.get_device_id(),
            "features": dict(f), "gige": bool(cam.is_gv_device()),
        }
        region = self._call(cam.get_region)
        roi = (int(region.x), int(region.y), int(region.width), int(region.height))
        current = self._call(cam.get_pixel_format_as_string)
        fmt = next((k for k, v in self._formats.items() if v and v.name == current), None)
        exposure = self._read_float(f["exposure"]) * 1e-6
        rate = self._read_float(f["rate"]) if f["rate"] else 1.0 / max(exposure, 1e-6)
        self._requested_rate = self._hw_rate = rate
        self._hw = {
            "pixel_format": fmt, "roi": roi, "binning": 1, "exposure_s": exposure,
            "frame_rate_hz": rate, "gain": self._read_gain(), "trigger_mode": self._read_trigger(),
        }
        self._region, self._crop = roi, (0, 0)
        self._info = dict(self._info_cache)  # what _validate_setting reads during open
        if fmt is None:  # a format this driver does not read: switch to one it does
            self._do_apply("pixel_format", next(k for k, v in self._formats.items() if v))
        else:
            self._source = self._formats[fmt]
            self._source_bits = self._source.bits
        self._payload = int(self._call(cam.get_payload))

    def _read_gain(self) -> float:
        f = self._features["gain"]
        if f is None or (self._gain_is_raw and not self._db_per_raw):
            return 0.0
        value = self._read_float(f) - self._gain_offset
        return float(max(value * (self._db_per_raw if self._gain_is_raw else 1.0), 0.0))

    def _read_trigger(self) -> str:
        cam = self._cam
        if not cam.is_feature_available("TriggerMode"):
            return "free_run"
        with contextlib.suppress(DeviceError):
            self._call(cam.set_string, "TriggerSelector", "FrameStart")
        if self._call(cam.get_string, "TriggerMode") != "On":
            return "free_run"
        return "software" if self._call(cam.get_string, "TriggerSource") == "Software" \
            else "hardware"

    def _do_get_info(self) -> dict[str, Any]:
        return dict(self._info_cache)

    def _do_get_settings(self) -> dict[str, Any]:
        return dict(self._hw)

    # ------------------------------------------------------------------ settings
    def _validate_setting(self, name: str, value: Any, pending: dict[str, Any]) -> Any:
        if name == "gain" and value != 0 and self._info["gain_range_db"][1] == 0:
            raise self._error(DeviceValueError, "the camera's gain cannot be set in dB",
                              "leave gain at 0, or for a GainRaw camera set "
                              "params.gain_db_per_raw from its manual")
        v = super()._validate_setting(name, value, pending)
        if name == "trigger_mode" and v != "free_run":
            needed = "Software" if v == "software" else self._line
            if needed not in self._sources:
                raise self._error(
                    DeviceValueError, f"trigger_mode={v!r} needs TriggerSource {needed!r}, "
                    f"the camera has {self._sources}",
                    "use another trigger mode" + ("" if v == "software" else
                                                  " or set params.trigger_line"),
                )
        return v

    def _do_apply(self, name: str, value: Any) -> Any:
        got = self._apply_one(name, value)
        self._hw[name] = got
        return got

    def _apply_one(self, name: str, value: Any) -> Any:
        cam, f = self._cam, self._features
        if name == "pixel_format":
            source = self._formats[value]
            self._call(cam.set_pixel_format_from_string, source.name,
                       what=f"setting PixelFormat {source.name}")
            self._source, self._source_bits = source, source.bits
            self._payload = int(self._call(cam.get_payload))
            return value
        if name == "roi":
            g = self._grid
            region, _ = aligned_region(value, g["sensor"], g["increments"], g["minimum"])
            self._call(cam.set_region, *region, what=f"setting the region {region}")
            r = self._call(cam.get_region)
            got = (int(r.x), int(r.y), int(r.width), int(r.height))
            x, y, w, h = value
            if not (got[0] <= x and got[1] <= y and x + w <= got[0] + got[2]
                    and y + h <= got[1] + got[3]):
                raise self._error(DeviceError, f"the camera took the region {got}, which "
                                  f"does not cover roi {value}", "choose another roi")
            self._region, self._crop = got, (x - got[0], y - got[1])
            self._payload = int(self._call(cam.get_payload))
            return value
        if name == "binning":
            return value  # on the host (block average), see the module notes
        if name == "exposure_s":
            self._write_number(f["exposure"], value * 1e6)
            got = self._read_float(f["exposure"]) * 1e-6
            self._write_rate(self._requested_rate, got)
            return got
        if name == "frame_rate_hz":
            return self._write_rate(value, self._hw["exposure_s"])
        if name == "gain":
            if f["gain"] is None or (self._gain_is_raw and not self._db_per_raw):
                return 0.0
            scale = self._db_per_raw if self._gain_is_raw else 1.0
            self._write_number(f["gain"], self._gain_offset + value / scale)
            return self._read_gain()
        # trigger_mode
        if value == "free_run":
            self._call(cam.clear_triggers, what="switching the triggers off")
        else:
            source = "Software" if value == "software" else self._line
            self._call(cam.set_trigger, source, what=f"setting the trigger source {source}")
        return value

    def _write_rate(self, requested: float, exposure_s: float) -> float:
        """Write ``min(requested, 1 / exposure_s)`` within the camera's range; return the
        requested rate as read back (the request itself when the exposure limits it)."""
        self._requested_rate = requested
        f = self._features
        if f["rate"] is None:
            self._hw_rate = min(requested, 1.0 / exposure_s)
            return requested
        lo, hi = self._info_cache["frame_rate_range_hz"]
        target = min(max(min(requested, 1.0 / exposure_s), lo), hi)
        if f["rate_enable"]:
            self._call(self._cam.set_boolean, f["rate_enable"], True)
        self._write_number(f["rate"], target)
        self._hw_rate = self._read_float(f["rate"])
        return requested if requested > 1.0 / exposure_s else self._hw_rate

    def _do_resulting_frame_rate_hz(self) -> float:
        rate = min(self._hw_rate, 1.0 / self._values["exposure_s"])
        if self._features.get("resulting_rate"):
            rate = min(rate, self._read_float(self._features["resulting_rate"]))
        return rate

    # ------------------------------------------------------------------ frames
    def _ensure_stream(self) -> Any:
        """The stream with a pool of buffers of the current payload (rebuilt when the
        payload changed), its output queue drained (stale frames re-queued)."""
        if self._stream is None or self._pool_payload != self._payload:
            self._stream = None
            stream = self._call(self._cam.create_stream, None, None, what="creating the stream")
            if self._gige:  # a frame still incomplete after this long is dropped
                stream.set_property("frame-retention", int(self._retention_s * 1e6))
            for _ in range(self._n_buffers):
                stream.push_buffer(self._arv.Buffer.new_allocate(self._payload))
            self._stream, self._pool_payload = stream, self._payload
        while (buf := self._stream.try_pop_buffer()) is not None:
            self._stream.push_buffer(buf)
        return self._stream

    def _to_frame(self, buf: Any) -> Frame | None:
        """The frame in ``buf`` (copied), or None when it is incomplete (counted)."""
        index = self._index
        self._index += 1
        status = buf.get_status()
        if status != self._arv.BufferStatus.SUCCESS:
            self._stats["incomplete"] += 1
            self._count_dropped()
            self._log.debug("%s: buffer %d status %s", self.device_id, buf.get_frame_id(),
                            status.value_nick)
            return None
        h, w = buf.get_image_height(), buf.get_image_width()
        hw = self._hw
        raw = None if (w, h) != self._region[2:] else decode(
            buf.get_data(), self._source, (h, w), hw["pixel_format"].startswith("rgb"))
        if raw is None:
            self._stats["incomplete"] += 1
            self._count_dropped()
            return None
        _, _, rw, rh = hw["roi"]
        image, saturated = frame_image(raw, self._crop, (rw, rh), hw["binning"],
                                       self._source_bits, hw["pixel_format"])
        stamp = buf.get_timestamp() or buf.get_system_timestamp()
        self._stats["completed"] += 1
        return Frame(image=image, index=index, device_timestamp_s=stamp * 1e-9,
                     host_timestamp_s=time.time(), exposure_s=hw["exposure_s"],
                     gain=hw["gain"], saturated_pixels=saturated)

    def _do_snap(self, timeout_s: float) -> Frame:
        stream = self._ensure_stream()
        cam = self._cam
        deadline = time.monotonic() + timeout_s
        dropped = 0
        self._call(cam.set_acquisition_mode, self._arv.AcquisitionMode.CONTINUOUS)
        self._call(cam.start_acquisition, what="starting the acquisition")
        try:
            if self._hw["trigger_mode"] == "software":
                self._call(cam.software_trigger, what="the software trigger")
            while (left := deadline - time.monotonic()) > 0:
                buf = stream.timeout_pop_buffer(max(int(left * 1e6), 1))
                if buf is None:
                    continue
                try:
                    frame = self._to_frame(buf)
                finally:
                    stream.push_buffer(buf)
                if frame is not None:
                    return frame
                dropped += 1
        finally:
            with contextlib.suppress(DeviceError):
                self._call(cam.stop_acquisition)
        self._check_alive()
        raise self._timeout(
            f"no complete frame within {timeout_s:g} s ({dropped} incomplete frame(s) "
            "dropped)", "check the trigger mode and source, the link (packet size, "
            "bandwidth), and that timeout_s exceeds the exposure",
        )

    def _check_alive(self) -> None:
        """Raise DeviceDisconnectedError when the camera no longer answers: a GigE
        camera is asked directly (:func:`gvcp_answers`, 0.6 s; Aravis's own register
        reads wait behind its heartbeat thread, 5 s and more for a dead camera), another
        camera through a feature read."""
        self._do_check_connection()
        if self._gige_ip is None:
            self._read_float(self._features["exposure"])
        elif not gvcp_answers(self._gige_ip):
            self._lost.set()
            raise self._lost_error(f"the GigE camera at {self._gige_ip} does not answer GVCP")

    def _do_start_stream(self, ring: FrameRing) -> None:
        stream = self._ensure_stream()
        self._call(self._cam.set_acquisition_mode, self._arv.AcquisitionMode.CONTINUOUS)
        self._call(self._cam.start_acquisition, what="starting the acquisition")
        self._start_grab(ring, lambda stop: self._grab_loop(stream, ring, stop), "aravis", 5.0)

    def _do_stop_stream(self) -> None:
        self._stop_grab()
        if not self._lost.is_set():
            self._call(self._cam.stop_acquisition, what="stopping the acquisition")

    def _do_trigger(self) -> None:
        self._call(self._cam.software_trigger, what="the software trigger")

    def _grab_loop(self, stream: Any, ring: FrameRing, stop: threading.Event) -> None:
        """Pop buffers (100 ms waits), hand frames to the ring, re-queue every buffer;
        after a second without buffers, probe the camera."""
        last_id: int | None = None
        idle_since = time.monotonic()
        try:
            while not stop.is_set():
                buf = stream.timeout_pop_buffer(100_000)
                if buf is None:
                    if self._lost.is_set():
                        raise self._lost_error("the camera was lost while streaming")
                    if time.monotonic() - idle_since > 1.0:
                        self._check_alive()
                        idle_since = time.monotonic()
                    continue
                idle_since = time.monotonic()
                try:
                    fid = int(buf.get_frame_id())
                    missing = frames_between(last_id, fid)
                    last_id = fid
                    if missing:
                        self._stats["id_gaps"] += missing
                        self._index += missing
                        self._count_dropped(missing)
                        ring.mark_dropped(missing)
                    frame = self._to_frame(buf)
                finally:
                    stream.push_buffer(buf)
                if frame is None:
                    ring.mark_dropped()
                else:
                    ring.put(frame)
        except DeviceDisconnectedError:
            self._lost.set()  # later calls fail fast instead of timing out on the link
            raise

    def _do_status(self) -> dict[str, Any]:
        out = {**super()._do_status(), **self._stats, "next_index": self._index}
        if self._stream is not None:
            names = ("completed", "failures", "underruns")
            out["aravis_stream"] = dict(zip(names, (int(v) for v in
                                                    self._stream.get_statistics()), strict=False))
        return out
