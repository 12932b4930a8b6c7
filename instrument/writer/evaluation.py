"""The files of ``diffuserlab holo evaluate``, written from the evaluation's record.

``recon.cgh.evaluate.run_evaluation`` evaluates and returns; this writes its four
files, each whole or not at all (:func:`~instrument.atomic.atomic_path`).
"""

from __future__ import annotations

import csv
from pathlib import Path

from ..atomic import atomic_path

__all__ = ["EVALUATION_FILES", "write_evaluation"]

#: The files :func:`write_evaluation` writes in its folder, in that order.
EVALUATION_FILES = ("records.csv", "summary.json", "table.md", "psnr_vs_seconds.png")


def write_evaluation(evaluation: dict, out: str | Path) -> list[Path]:
    """Write an evaluation's records, summary, table and chart to the folder ``out``.

    Parameters
    ----------
    evaluation : dict
        From ``recon.cgh.evaluate.run_evaluation`` (``records``, ``record``,
        ``table``).
    out : str or pathlib.Path
        The folder (created with its parents).

    Returns
    -------
    list of pathlib.Path
        The files of :data:`EVALUATION_FILES` in ``out``: ``records.csv`` (one row per
        image, factor, method and seed; each record's fields but its ``curve``),
        ``summary.json``, ``table.md`` and ``psnr_vs_seconds.png``
        (``recon.cgh.evaluate.psnr_vs_seconds_figure``, 110 dpi).

    Raises
    ------
    OSError
        A file cannot be written (a full disk named with its free space); the files
        already written stay.
    """
    import matplotlib.pyplot as plt

    from recon.cgh.evaluate import psnr_vs_seconds_figure

    from ..atomic import write_json

    out = Path(out)
    records = evaluation["records"]
    fields = [k for k in records[0] if k != "curve"]
    with atomic_path(out / "records.csv") as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(records)
    write_json(out / "summary.json", evaluation["record"])
    with atomic_path(out / "table.md") as tmp:
        tmp.write_text(evaluation["table"])
    fig = psnr_vs_seconds_figure(records)
    try:
        with atomic_path(out / "psnr_vs_seconds.png") as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
    return [out / n for n in EVALUATION_FILES]
