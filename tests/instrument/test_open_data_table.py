"""The table of docs/open-data.md ("Which tool opens what") is what the field's tools
make of fresh outputs: every pair the table calls right is right by the checks of
``benchmarks.open_data`` (axes, shape, pixel size in µm, frame interval, each
plane's depth, channels), every other pair is wrong there and its cell names a
stated limit, and the count the docs give is the measured one.

The outputs are written by the simulated bench and the project's commands (about
two minutes on a loaded 2-core machine). ImageJ 1.x (Debian's ``imagej``) is run
where it is installed; ``DIFFUSERLAB_REQUIRE_INTEROP=1`` (CI) makes a missing tool
fail, not skip.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from benchmarks import open_data
from tests.drivers.interop.clients import client

DOC = Path(__file__).resolve().parents[2] / "docs" / "open-data.md"
REQUIRED = os.environ.get("DIFFUSERLAB_REQUIRE_INTEROP") == "1"

for module, package in [("bioio", "bioio"), ("bioio_ome_zarr", "bioio-ome-zarr"),
                        ("bioio_ome_tiff", "bioio-ome-tiff"),
                        ("bioio_tifffile", "bioio-tifffile"), ("ome_zarr", "ome-zarr"),
                        ("napari_ome_zarr", "napari-ome-zarr"), ("xarray", "xarray")]:
    client(module, package)


def _doc_table() -> tuple[list[str], dict[tuple[str, str], str], str]:
    """The docs' table: its tools, ``{(output, tool): cell}`` and the text below it."""
    text = DOC.read_text()
    section = text[text.index("## Which tool opens what"):]
    lines = [ln for ln in section.splitlines() if ln.startswith("| ")]  # no |---|
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    cells = {}
    for line in lines[1:]:
        row = [c.strip() for c in line.strip("|").split("|")]
        for tool, cell in zip(header[1:], row[1:], strict=True):
            if cell != "-":
                cells[row[0], tool] = cell
    return header[1:], cells, section


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    if open_data.imagej_command() is None and REQUIRED:
        pytest.fail("ImageJ is not installed (apt-get install imagej; scripts/system-deps.sh)")
    outputs = open_data.make_outputs(tmp_path_factory.mktemp("open_data"))
    return outputs, open_data.measure(outputs)


def test_the_table_has_one_cell_per_pair_measured(measured):
    outputs, found = measured
    tools, cells, _ = _doc_table()
    assert tools == list(open_data.TOOLS)
    assert set(cells) == set(found), set(cells) ^ set(found)


def test_every_right_in_the_table_is_right_and_every_other_cell_states_a_limit(measured):
    _, found = measured
    _, cells, section = _doc_table()
    notes = set(re.findall(r"^\((\d+)\) ", section, re.MULTILINE))
    no_imagej = open_data.imagej_command() is None
    for pair, cell in cells.items():
        if no_imagej and pair[1] == "ImageJ 1.x":
            continue  # not installed here, and not required: see the fixture
        if cell.startswith("right"):
            assert found[pair] == [], (pair, found[pair])
        else:
            assert found[pair], (pair, "the docs say wrong, the tool reads it right")
            cited = [n.strip() for group in re.findall(r"\(([\d, ]+)\)", cell)
                     for n in group.split(",")]
            assert cited and set(cited) <= notes, (pair, cell, "cites no stated limit")


def test_the_count_in_the_docs_is_the_measured_count(measured):
    _, found = measured
    _, _, section = _doc_table()
    right = sum(not wrong for wrong in found.values())
    assert f"**{right} of {len(found)} pairs right**" in section


def test_the_checks_fail_a_wrong_reading():
    """"Right" is checked, not assumed: an output that opens with the wrong pixel
    size, axes, interval or depths is wrong."""
    e = open_data.Expect("x", Path("x"), "zarr", "zyx", (3, 4, 5), 13.0, z_um=[1.0, 2.0, 4.0])
    good = open_data.Reading("zyx", (3, 4, 5), (13.0, 13.0), None, [1.0, 2.0, 4.0])
    assert open_data.judge(e, good) == []
    for change in [{"axes": "tyx"}, {"shape": (3, 5, 4)}, {"yx_um": (13.0, 26.0)},
                   {"yx_um": None}, {"z_um": [1.0, 2.5, 4.0]}, {"z_um": None}]:
        wrong = open_data.Reading(**{**vars(good), **change})
        assert open_data.judge(e, wrong), change
    video = open_data.Expect("v", Path("v"), "zarr", "tyx", (3, 4, 5), 13.0, t_s=0.04)
    seen = open_data.Reading("tyx", (3, 4, 5), (13.0, 13.0), None)
    assert open_data.judge(video, seen) == ["frame interval None (not 0.04 s)"]


def test_an_ome_tiff_carries_its_pixel_size_in_the_tiff_resolution_tags(tmp_path, capsys):
    """ImageJ 1.x (Fiji without Bio-Formats) reads no OME-XML: the pixel size is
    also in the TIFF's resolution tags (pixels per centimetre), for a ``recon``
    still and a ``runs export`` OME-TIFF."""
    import tifffile

    from instrument.cli import main

    rng = np.random.default_rng(0)
    psf = np.zeros((40, 48), np.float32)
    psf[18:22, 20:26] = 1.0
    np.save(tmp_path / "p.npy", psf)
    np.save(tmp_path / "r.npy", psf + 0.05 * rng.random((40, 48)).astype(np.float32))
    assert main(["recon", "--psf", str(tmp_path / "p.npy"), "--raw",
                 str(tmp_path / "r.npy"), "--method", "wiener", "--bin", "2",
                 "--pitch-um", "3.45", "--out", str(tmp_path / "o.png")]) == 0
    np.save(tmp_path / "s.npy", rng.random((3, 16, 20)).astype(np.float32))
    assert main(["runs", "import-psf", str(tmp_path / "s.npy"), "--depths", "20,30,40",
                 "--pitch-um", "2.5", "--out", str(tmp_path / "p.zarr")]) == 0
    assert main(["runs", "export", str(tmp_path / "p.zarr"), "--out",
                 str(tmp_path / "p.ome.tif")]) == 0
    capsys.readouterr()
    for name, um in [("o.tif", 6.9), ("p.ome.tif", 2.5)]:
        with tifffile.TiffFile(tmp_path / name) as tif:
            tags = tif.pages[0].tags
            assert tif.is_ome
            assert tags["ResolutionUnit"].value == tifffile.RESUNIT.CENTIMETER, name
            for tag in ("XResolution", "YResolution"):
                num, den = tags[tag].value
                assert 1e4 * den / num == pytest.approx(um, rel=1e-6), (name, tag)
