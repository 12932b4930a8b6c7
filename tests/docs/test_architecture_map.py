"""The architecture map (docs/images/architecture.png, its numbers in
docs/images/architecture.json and the table in docs/architecture.md) stays true: the
checkout is measured again and compared with what is committed.

When this fails, redraw the map (the walk profiled again)::

    python scripts/architecture_map.py docs/images/architecture.png --docs docs/architecture.md

or, when only lines and imports have moved, add ``--keep-walk`` (seconds, not minutes).
"""

import importlib.util
import json
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
PNG = ROOT / "docs" / "images" / "architecture.png"
JSON = PNG.with_suffix(".json")
PAGE = ROOT / "docs" / "architecture.md"

_spec = importlib.util.spec_from_file_location("architecture_map",
                                               ROOT / "scripts" / "architecture_map.py")
amap = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(amap)


def _committed() -> dict:
    return json.loads(JSON.read_text(encoding="utf-8"))


def test_the_committed_map_is_the_checkout_measured():
    measured = amap.summary(*amap.measure(), None)
    stale = amap.drift(_committed(), measured)
    assert not stale, ("the architecture map is stale; redraw it: python "
                       "scripts/architecture_map.py docs/images/architecture.png --docs "
                       "docs/architecture.md [--keep-walk]\n" + "\n".join(stale))


def test_the_picture_and_the_page_are_drawn_from_the_committed_numbers():
    """The PNG carries the SHA-256 of the JSON it was drawn with, and the page's table
    is the JSON's: none of the three redrawn without the others."""
    data = _committed()
    assert Image.open(PNG).text.get("Description") == amap.digest(data)
    page = PAGE.read_text(encoding="utf-8")
    table = page.split(amap.DOCS_START, 1)[1].split(amap.DOCS_END, 1)[0]
    assert table.strip() == amap.docs_table(data)
    assert data["walk"], "the committed map has no walk of diffuserlab recon"


def test_drift_names_what_the_review_found_stale():
    """The map of 84 commits before: 599 import statements where 626 were measured and
    the run store's part at 734 lines where it had 401; and a part, an import direction
    that appeared, and numbers inside the slack that are no drift."""
    now = {"packages": {"instrument": 23_700}, "parts": {"instrument.runs.runstore": 401},
           "imports": {"instrument -> recon": 196}, "imports_total": 626, "upward": 0}
    drawn = json.loads(json.dumps(now))
    assert amap.drift(drawn, now) == []
    drawn["packages"]["instrument"] = 23_000  # 3 %: still true
    drawn["imports"]["instrument -> recon"] = 190
    assert amap.drift(drawn, now) == []
    drawn["imports_total"], drawn["parts"]["instrument.runs.runstore"] = 599, 734
    assert amap.drift(drawn, now) == ["part instrument.runs.runstore: drawn 734, now 401",
                                      "imports in all: drawn 599, now 626"]
    now["imports"]["gui -> recon"] = 20
    drawn["parts"]["instrument.runs.runstore"], drawn["imports_total"] = 401, 626
    drawn["upward"] = 1
    assert amap.drift(drawn, now) == ["import gui -> recon: new", "upward imports: drawn 1, now 0"]


def test_the_drawing_is_deterministic(tmp_path):
    """The same numbers give the same PNG bytes (no version or date in it), so a redraw
    of an unchanged checkout changes no file."""
    lines, edges = amap.measure()
    steps = _committed()["walk"]
    for name in ("a.png", "b.png"):
        amap.draw(tmp_path / name, lines, edges, steps, description="x")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    assert amap.summary_json(amap.summary(lines, edges, steps)) == amap.summary_json(
        amap.summary(lines.copy(), edges.copy(), list(steps)))
