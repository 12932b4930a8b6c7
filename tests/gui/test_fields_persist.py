"""Every field of the window's generated forms (gui.forms.OptionsForm: the live
reconstruction's, the batch reconstruction's) and the depth fields come back after
the window is closed the operator's way and opened again."""

from __future__ import annotations

from PySide6.QtWidgets import QCheckBox, QComboBox, QDoubleSpinBox, QLineEdit, QSpinBox


def _set_other(widget) -> object:
    """Give ``widget`` a value other than the one it shows; returns what it shows."""
    if isinstance(widget, QCheckBox):
        widget.setChecked(not widget.isChecked())
        return widget.isChecked()
    if isinstance(widget, QComboBox):
        if widget.isEditable():
            widget.setEditText("7")
        else:
            widget.setCurrentIndex((widget.currentIndex() + 1) % widget.count())
        return widget.currentText()
    if isinstance(widget, QSpinBox | QDoubleSpinBox):
        step = 1 if widget.value() + 1 <= widget.maximum() else -1
        widget.setValue(widget.value() + step)
        return widget.value()
    if isinstance(widget, QLineEdit):
        widget.setText("7")
        return widget.text()
    raise TypeError(type(widget).__name__)


def _shown(widget) -> object:
    if isinstance(widget, QCheckBox):
        return widget.isChecked()
    if isinstance(widget, QComboBox):
        return widget.currentText()
    if isinstance(widget, QSpinBox | QDoubleSpinBox):
        return widget.value()
    return widget.text()


def _fields(w) -> dict:
    out = {"live depth": w.live.depth}
    for name, form in (("live", w.live.live_form), ("live", w.live.recon_form),
                       ("batch", w.record.run_form), ("batch", w.record.recon_form)):
        for field, widget in form.widgets.items():
            out[f"{name} {field}"] = widget
    return out


def test_every_form_field_comes_back_after_a_close(qapp, tmp_path, monkeypatch, wait):
    monkeypatch.setenv("DIFFUSERLAB_GUI_SETTINGS", str(tmp_path / "gui.ini"))
    from gui.app import MainWindow
    from gui.session import Session

    first = MainWindow(Session(None, simulate=True, scene="none"))
    first.show()
    fields = _fields(first)
    assert len(fields) >= 10 and "batch depth_mm" in fields
    typed = {name: _set_other(widget) for name, widget in fields.items()}
    first.close()  # the window's own close, with no bench connected: asks nothing
    # (no job), stores every field, closes (it stayed open: Qt ignored the nested close)
    wait(lambda: not first.isVisible(), 30.0, "the window to close")
    first.deleteLater()
    second = MainWindow(Session(None, simulate=True, scene="none"))
    try:
        back = {name: _shown(widget) for name, widget in _fields(second).items()}
        lost = {k: (typed[k], back.get(k)) for k in typed if back.get(k) != typed[k]}
        assert not lost, f"fields not remembered (typed, shown): {lost}"
    finally:
        second.shutdown()
        second.deleteLater()
