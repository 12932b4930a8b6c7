"""The operator's day on the emulated bench (the real drivers on protocol emulators,
:class:`instrument.devices.emulated_bench.EmulatedBench`), in a real window for 5 minutes: the
PSF sweep from the GUI while the Devices panel polls the APT stage, an LED array
unplugged at its emulator and reconnected."""

from __future__ import annotations

from tests.gui.operator_day_checks import check_day


def test_operator_day_on_the_emulated_bench(tmp_path, monkeypatch):
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    from soak.soak import print_summary, run_day, summarise

    report = run_day(emulated=True, minutes=5.0, alignment_s=20.0, work=str(tmp_path / "day"))
    figures = summarise(report)
    print_summary(figures, report)
    check_day(report, figures, extra_steps=("alignment refused without a mask seed",
                                            "dark refused: the flat received no light"))
