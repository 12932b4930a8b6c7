"""The camera and SLM drivers import their optional libraries when a device opens, and a
missing one is an error naming the extra or the Debian package."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest

from drivers.aravis_camera import AravisCamera
from drivers.errors import DeviceDisconnectedError, MissingDependencyError
from drivers.slm_window import FullscreenSlm


def test_importing_the_drivers_loads_no_optional_library():
    code = ("import sys, drivers.aravis_camera, drivers.v4l2_camera, drivers.slm_window; "
            "print(sorted(m for m in ('gi', 'PySide6', 'cv2') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60)
    assert out.stdout.strip() == "[]"


def test_aravis_without_pygobject_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "gi", None)  # import gi -> ImportError
    cam = AravisCamera("cam", camera_name="Fake_1", fake_interface=True)
    with pytest.raises(MissingDependencyError, match=r"diffuserlab\[hardware\]") as info:
        cam.open()
    assert isinstance(info.value, ImportError) and not cam.is_open


def test_aravis_without_the_typelib_names_the_apt_package(monkeypatch):
    import gi

    def missing(namespace, version):
        raise ValueError(f"Namespace {namespace} not available")

    monkeypatch.setattr(gi, "require_version", missing)
    with pytest.raises(MissingDependencyError, match="apt-get install gir1.2-aravis-0.8"):
        AravisCamera("cam", camera_name="Fake_1", fake_interface=True).open()


def test_slm_window_without_pyside6_names_the_extra(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "PySide6" else real(name, *a))
    with pytest.raises(MissingDependencyError, match=r"diffuserlab\[gui\]"):
        FullscreenSlm("slm", display=":0").open()


def test_slm_window_without_a_display_says_so(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(DeviceDisconnectedError, match="DISPLAY"):
        FullscreenSlm("slm").open()
