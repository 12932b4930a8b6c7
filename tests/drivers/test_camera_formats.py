"""Camera pixel formats beyond mono8/12/16 and automatic exposure/gain, for the Aravis
driver: PFNC packed Mono10p/Mono12p unpacked against a packer written bit by bit from
the GenICam PFNC definition (LSB first), Bayer mosaics demosaiced (OpenCV's naming
checked against GenICam's), and, on libaravis's fake camera, ExposureAuto/GainAuto
switched off with read-back and the colour formats delivered.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.aravis_camera import AravisCamera
from drivers.aravis_support import FORMATS, Source, decode, import_aravis
from drivers.camera_image import (
    BAYER_PATTERNS,
    demosaic,
    frame_image,
    unpack_mono10p,
    unpack_mono12p,
)

FAKE = dict(gain_db_per_raw=1.0, pixel_pitch_um=5.5)
PFNC = {"Mono10": 0x01100003, "Mono10p": 0x010A0046, "Mono12p": 0x010C0047,
        "BayerRG16": 0x0110002F}


def pack_lsb_first(pixels: np.ndarray, bits: int) -> bytes:
    """PFNC "p" packing: pixel k occupies bits k*bits .. (k+1)*bits-1 of a little-endian
    bit stream (the GenICam PFNC definition of Mono10p / Mono12p)."""
    acc = 0
    for k, p in enumerate(int(v) for v in pixels):
        acc |= p << (k * bits)
    return acc.to_bytes(-(-len(pixels) * bits // 8), "little")


@pytest.mark.parametrize(("unpack", "bits"), [(unpack_mono10p, 10), (unpack_mono12p, 12)])
@pytest.mark.parametrize("count", [1, 3, 4, 7, 64, 1001])
def test_packed_formats_unpack(unpack, bits, count):
    rng = np.random.default_rng(count + bits)
    pixels = rng.integers(0, 2**bits, count)
    pixels[:2] = [2**bits - 1, 0][: min(2, count)]
    assert np.array_equal(unpack(pack_lsb_first(pixels, bits), count), pixels)


def test_mono10p_known_bytes():
    # pixels 0x3FF, 0, 0x155, 0x2AA at bits 0, 10, 20, 30: 0x3FF | 0x155 << 20 |
    # 0x2AA << 30 = 0xAA955003FF, little-endian FF 03 50 95 AA
    assert list(unpack_mono10p(bytes.fromhex("FF035095AA"), 4)) == [0x3FF, 0, 0x155, 0x2AA]


def mosaic_of(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """The Bayer mosaic a GenICam ``Bayer<pattern>`` sensor records of ``rgb``."""
    colours = pattern + {"RG": "GB", "GR": "BG", "GB": "RG", "BG": "GR"}[pattern]
    out = np.zeros(rgb.shape[:2], rgb.dtype)
    for (dy, dx), c in zip(((0, 0), (0, 1), (1, 0), (1, 1)), colours, strict=True):
        out[dy::2, dx::2] = rgb[dy::2, dx::2, "RGB".index(c)]
    return out


@pytest.mark.parametrize("pattern", sorted(BAYER_PATTERNS))
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_demosaic_follows_the_genicam_pattern(pattern, dtype):
    full = np.iinfo(dtype).max
    flat = np.empty((8, 10, 3), dtype)
    flat[...] = np.array([0.8, 0.4, 0.2]) * full
    assert np.array_equal(demosaic(mosaic_of(flat, pattern), pattern)[2:-2, 2:-2],
                          flat[2:-2, 2:-2])
    yy, xx = np.mgrid[0:32, 0:40]  # a smooth colour image: bilinear is near exact
    smooth = np.stack([xx * 3 + 20, yy * 4 + 10, (xx + yy) * 2 + 5], -1).astype(dtype)
    out = demosaic(mosaic_of(smooth, pattern), pattern).astype(float)
    assert np.abs(out - smooth)[2:-2, 2:-2].max() <= 1


def test_decode_each_layout():
    rng = np.random.default_rng(1)
    img = rng.integers(0, 1024, (4, 6))
    assert np.array_equal(decode(pack_lsb_first(img.ravel(), 10), Source("Mono10p", 10, "p10"),
                                 (4, 6), False), img)
    assert decode(b"\0" * 20, Source("Mono10p", 10, "p10"), (4, 6), False) is None  # short
    words = img.astype("<u2").tobytes()
    assert np.array_equal(decode(words, Source("Mono10", 10, "u16"), (4, 6), False), img)
    rgb = rng.integers(0, 256, (4, 6, 3)).astype(np.uint8)
    assert np.array_equal(decode(rgb.tobytes(), Source("RGB8", 8, "rgb"), (4, 6), True), rgb)
    m16 = mosaic_of(rng.integers(0, 65536, (4, 6, 3)).astype(np.uint16), "GB")
    raw = decode(m16.astype("<u2").tobytes(), Source("BayerGB16", 16, "bayer16"), (4, 6), False)
    assert np.array_equal(raw, m16)
    colour = decode(m16.astype("<u2").tobytes(), Source("BayerGB16", 16, "bayer16"), (4, 6), True)
    assert np.array_equal(colour, demosaic(m16, "GB"))


def test_frame_image_bins_and_scales_colour():
    rgb = np.arange(4 * 6 * 3, dtype=np.uint16).reshape(4, 6, 3) * 100
    image, saturated = frame_image(rgb, (0, 0), (6, 4), 2, 16, "rgb8")
    assert image.shape == (2, 3, 3) and image.dtype == np.uint8
    expected = np.rint(rgb.reshape(2, 2, 3, 2, 3).mean(axis=(1, 3))).astype(np.uint32) >> 8
    assert np.array_equal(image, expected)
    rgb[1, 1, 2] = 65535
    assert frame_image(rgb, (0, 0), (6, 4), 1, 16, "rgb16")[1] == 1


def test_format_table_covers_the_issue():
    names = {s.name for cands in FORMATS.values() for s in cands}
    assert {"Mono10", "Mono10p", "Mono12p", "BayerRG8", "BayerBG16", "RGB8"} <= names


# ------------------------------------------------------------------ on libaravis's fake camera
@pytest.fixture
def fake_xml(tmp_path):
    """The fake camera with ExposureAuto (on its scratch register, whose power-up value
    0x12345678 is made to read "Continuous", as a Blackfly S powers up) and the formats
    it does not have (Mono10, Mono10p, Mono12p, BayerRG16) added to its own GenICam
    file; the original file is put back afterwards (the setting is global to the
    process)."""
    arv, _ = import_aravis("test")
    arv.enable_interface("Fake")
    cam = arv.Camera.new("Fake_1")
    xml = cam.get_device().get_genicam_xml()[0]
    xml = xml if isinstance(xml, str) else bytes(xml).decode()
    del cam
    original = tmp_path / "fake.xml"
    original.write_text(xml)
    entries = "".join(f'<EnumEntry Name="{n}" NameSpace="Standard"><Value>{v}</Value>'
                      "</EnumEntry>" for n, v in PFNC.items())
    xml2 = xml.replace("<pValue>PixelFormatRegister</pValue>",
                       entries + "<pValue>PixelFormatRegister</pValue>", 1)
    auto = ('<Enumeration Name="ExposureAuto" NameSpace="Standard">'
            '<EnumEntry Name="Off" NameSpace="Standard"><Value>0</Value></EnumEntry>'
            '<EnumEntry Name="Continuous" NameSpace="Standard"><Value>305419896</Value>'
            "</EnumEntry>"
            "<pValue>ExposureAutoRegister</pValue></Enumeration>"
            '<IntReg Name="ExposureAutoRegister" NameSpace="Custom"><Address>0x1F0</Address>'
            "<Length>4</Length><AccessMode>RW</AccessMode><pPort>Device</pPort>"
            "<Sign>Unsigned</Sign><Endianess>BigEndian</Endianess></IntReg>")
    xml2 = xml2.replace('<Enumeration Name="GainAuto"', auto + '<Enumeration Name="GainAuto"', 1)
    extended = tmp_path / "fake-extended.xml"
    extended.write_text(xml2)
    arv.set_fake_camera_genicam_filename(str(extended))
    yield arv
    arv.set_fake_camera_genicam_filename(str(original))


def test_automatic_exposure_is_switched_off(fake_xml):
    assert fake_xml.Camera.new("Fake_1").get_string("ExposureAuto") == "Continuous"
    with AravisCamera("cam", camera_name="Fake_1", fake_interface=True, **FAKE) as cam:
        raw = cam._cam
        assert cam.info["automatic_off"] == ["ExposureAuto", "GainAuto"]
        assert raw.get_string("ExposureAuto") == "Off" and raw.get_string("GainAuto") == "Off"
        cam.exposure_s = 0.004
        assert cam.exposure_s == pytest.approx(0.004)
        assert {"mono10", "mono12", "rgb8", "rgb16", "bayer8", "bayer16"} <= set(
            cam.info["pixel_formats"])
        cam.pixel_format = "mono10"
        assert raw.get_pixel_format_as_string() == "Mono10"
        cam.pixel_format = "bayer16"
        assert raw.get_pixel_format_as_string() == "BayerRG16"
        assert cam.info["bayer_pattern"] == "RG"


def test_colour_camera_frames(tmp_path):
    """The fake camera's BayerRG8: rgb8 demosaiced (rows, cols, 3), bayer8 raw; a raw
    mosaic refuses binning and odd offsets (its pattern would change)."""
    with AravisCamera("cam", camera_name="Fake_1", fake_interface=True, **FAKE) as cam:
        cam.apply_settings({"pixel_format": "rgb8", "roi": (0, 0, 64, 48), "binning": 2})
        frame = cam.snap()
        assert frame.image.shape == (24, 32, 3) and frame.image.dtype == np.uint8
        cam.apply_settings({"pixel_format": "bayer8", "binning": 1})
        raw = cam.snap().image
        assert raw.shape == (48, 64)
        with pytest.raises(Exception, match="binning 1 and an even roi"):
            cam.apply_settings({"roi": (1, 0, 32, 32)})
        with pytest.raises(Exception, match="binning 1 and an even roi"):
            cam.binning = 2
