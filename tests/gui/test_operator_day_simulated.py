"""The operator's day on the simulated bench, in a real window: Xvfb with the xcb platform,
openbox, the real ``diffuserlab gui`` driven by xdotool (:mod:`soak.operator_day`) for
5 minutes. Crashes, lost frames, reference leaks and freezes fail it; its lateness
figures are printed (the goals are ``python -m soak.benchmark soak``'s)."""

from __future__ import annotations

from tests.gui.operator_day_checks import check_day


def test_operator_day_on_the_simulated_bench(tmp_path, monkeypatch):
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    from soak.soak import print_summary, run_day, summarise

    report = run_day(emulated=False, minutes=5.0, alignment_s=20.0, work=str(tmp_path / "day"))
    figures = summarise(report)
    print_summary(figures, report)
    check_day(report, figures, extra_steps=("alignment",))
