"""A progress bar's ETA goes when its job ends, and a failed or cancelled job's bar
keeps no count (issue 67: the bars kept their last text and ETA)."""

from __future__ import annotations

import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


def test_the_eta_goes_when_a_job_completes_and_the_count_when_it_fails(qapp):
    from gui.panels.common import JobProgress

    bar = JobProgress("frames")
    bar.start(10)
    bar.report(5, 10, eta_s=30.0)
    assert "ETA" in bar.label.text() and bar.bar.text() == "5 / 10 frames (50 %)"
    bar.finish("")  # failed
    assert bar.label.text() == "" and bar.bar.text() == "" and bar.eta_s() is None
    bar.start(10)
    bar.report(10, 10, eta_s=0.0)
    bar.finish()  # completed: the count stays, the ETA goes
    assert "ETA" not in bar.label.text() and bar.label.text().startswith("finished in")
    assert bar.bar.text() == "10 / 10 frames (100 %)"
    bar.start(10)
    assert bar.bar.text() == "0 / 10 frames (0 %)"  # a new job counts again
    bar.close()
    bar.deleteLater()


def test_a_cancelled_batch_leaves_no_eta(record_panel):
    record_panel.batch_progress.start(8)
    record_panel.batch_progress.report(3, 8, eta_s=12.0)
    record_panel.on_batch_done("v.zarr", {"product": "recon_auto", "reconstructed": 3,
                                          "skipped": 0, "cancelled": True, "seconds": 4.0,
                                          "fps": 0.8, "workers": 1, "failed": []})
    assert "ETA" not in record_panel.batch_progress.label.text()
    assert record_panel.batch_progress.bar.text() == ""
