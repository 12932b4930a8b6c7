"""On a laptop's screen (issue 67): the Calibration panel's parameter box drops each
field's help line when it is short (it showed 1.5 fields at a time on 1366x768; the
help stays in the tooltip), and the Live panel's counters are top-aligned with room
for three lines (a wrapped text drawn over the raw view's axis title; both looked at
in screenshots of the real window on a 1366x768 Xvfb)."""

from __future__ import annotations

import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


def test_the_parameter_box_drops_its_help_lines_when_short(qapp, tmp_path, wait):
    os.environ["DIFFUSERLAB_GUI_SETTINGS"] = str(tmp_path / "gui.ini")
    from gui.panels.calibration import CalibrationPanel
    from gui.session import Session

    panel = CalibrationPanel(Session(None, simulate=True, scene="none"))
    panel.routine.setCurrentText("psf-sweep")
    panel.show()
    try:
        panel.resize(900, 700)
        wait(lambda: panel.params.viewport().height() >= panel.HINTS_MIN_HEIGHT_PX, 10,
             "a tall parameter box")
        wait(lambda: not any(h.isHidden() for h in panel._hints), 10, "the help lines")
        panel.resize(900, 300)
        wait(lambda: panel.params.viewport().height() < panel.HINTS_MIN_HEIGHT_PX, 10,
             "a short parameter box")
        wait(lambda: all(h.isHidden() for h in panel._hints), 10, "no help lines")
        page = panel.forms.currentWidget()
        fields = list(panel.fields["psf-sweep"].values())
        port = panel.params.viewport().height()
        whole = [w for w in fields if w.mapTo(page, w.rect().bottomLeft()).y() <= port]
        assert len(whole) >= 2, (port, len(whole))
        assert all(w.toolTip() for w in fields)  # the help, still at hand
    finally:
        panel.close()
        panel.deleteLater()


def test_the_counters_under_a_view_have_room_for_three_lines(qapp, tmp_path):
    os.environ["DIFFUSERLAB_GUI_SETTINGS"] = str(tmp_path / "gui.ini")
    from PySide6.QtCore import Qt

    from gui.panels.live import LivePanel
    from gui.session import Session

    panel = LivePanel(Session(None, simulate=True, scene="none"))
    try:
        for label in (panel.raw_stats, panel.recon_stats):
            assert label.alignment() & Qt.AlignmentFlag.AlignTop
            assert label.minimumHeight() >= 3 * label.fontMetrics().lineSpacing()
    finally:
        panel.close()
        panel.deleteLater()
