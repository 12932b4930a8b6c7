"""The bench process's address and jobs, in the Devices panel: every client's jobs.

:class:`BenchJobs` shows where a notebook attaches (the bench process's address and
its connection file, :mod:`instrument.bench.bench_connection`) and lists the bench
process's running jobs, whichever client started them (a notebook's recording, the
window's own calibration run): id, name, owner, progress and the devices each holds
(:meth:`instrument.bench.bench_process.BenchClient.jobs`). *Stop job* stops the selected one
after a confirmation that names its owner. The list follows the bench's ``job``
events, and its progress is read again once a second while a job runs, on a worker
(a bench process that hangs never holds up the window).
"""

from __future__ import annotations

from typing import Any

from PySide6.QtCore import Qt, QTimer
from PySide6.QtWidgets import (
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QMessageBox,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from ..session import Session
from ..workers import DEVICE_NICE, Job

__all__ = ["BenchJobs", "progress_text"]

#: How often the running jobs' progress is read again, ms (only while one runs).
PROGRESS_PERIOD_MS = 1000


def progress_text(progress: Any) -> str:
    """A job's last progress in a few words (``recorded 120``, ``frame 4/32``)."""
    if progress is None:
        return "starting"
    if isinstance(progress, dict):
        if "recorded" in progress:
            return f"recorded {progress['recorded']}"
        if "kind" in progress:
            return str(progress["kind"])
        return ", ".join(f"{k} {v}" for k, v in list(progress.items())[:2])
    done, total = getattr(progress, "frames_done", None), getattr(progress, "frames_total", None)
    if done is not None and total:
        return f"frame {done}/{total}"
    return str(progress)[:40]


class BenchJobs(QWidget):
    """The bench process's address and its running jobs (module docstring)."""

    def __init__(self, session: Session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        #: The running jobs listed, by row (:class:`~instrument.bench.bench_job_handle.JobInfo`).
        self.infos: list = []
        #: Every job the last read returned (running and recently ended).
        self.all_infos: list = []
        self._reading: Job | None = None
        self._again = False
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.where = QLabel("")
        self.where.setObjectName("bench-where")
        self.where.setWordWrap(True)
        self.where.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.where.setToolTip("a notebook attaches with BenchClient.connect() (the file) "
                              "or BenchClient(address=..., authkey=...)")
        layout.addWidget(self.where)
        row = QHBoxLayout()
        self.list = QListWidget()
        self.list.setObjectName("bench-jobs")
        self.list.setMaximumHeight(80)
        row.addWidget(self.list, 1)
        self.stop_button = QPushButton("Stop job")
        self.stop_button.setObjectName("stop-bench-job")
        self.stop_button.setToolTip("stop the selected job, whichever client started it")
        self.stop_button.clicked.connect(self.stop_selected)
        row.addWidget(self.stop_button, 0, Qt.AlignmentFlag.AlignTop)
        layout.addLayout(row)
        self.timer = QTimer(self)
        self.timer.setInterval(PROGRESS_PERIOD_MS)
        self.timer.timeout.connect(self.refresh)
        session.changed.connect(self.refresh)
        session.device_event.connect(self.on_event)
        self.refresh()

    def on_event(self, event) -> None:
        if event.kind == "job":
            self.refresh()

    def refresh(self) -> None:
        """Read the bench process's address, and its jobs on a worker (a bench process
        that hangs never holds up the window); the list follows when they come."""
        service = self.session.service
        self.setVisible(service is not None)
        if service is None or self.session.lost is not None:
            self.where.setText("")
            self._show([])
            return
        where = getattr(service, "address", None)
        path = getattr(service, "connection_file", None)
        self.where.setText(("bench process: in this process" if where is None else
                            f"bench process: {where}")
                           + (f"; connection file {path}" if path else ""))
        if self._reading is not None and self._reading.running:
            self._again = True  # read once more when this read ends
            return
        self._again = False
        job = Job(lambda job: service.jobs(), name="bench-jobs", owner=self, nice=DEVICE_NICE)
        job.succeeded.connect(lambda infos: self._show(infos, service))
        job.finished.connect(self._read_again)
        self._reading = job
        job.start()

    def _read_again(self) -> None:
        if self._again:
            self.refresh()

    def _show(self, infos: list, service=None) -> None:
        if service is not None and service is not self.session.service:
            return  # the bench was closed or restarted meanwhile
        self.all_infos = list(infos)
        jobs = [i for i in infos if i.state == "running"]
        selected = self.selected()
        self.infos = jobs
        self.list.clear()
        for info in jobs:
            text = (f"job {info.id} {info.name} of {info.owner}: {progress_text(info.progress)}"
                    + (f" (holds {', '.join(info.holds)})" if info.holds else ""))
            self.list.addItem(QListWidgetItem(text))
            if selected is not None and info.id == selected.id:
                self.list.setCurrentRow(self.list.count() - 1)
        self.stop_button.setEnabled(bool(jobs))
        if jobs and not self.timer.isActive():
            self.timer.start()
        elif not jobs:
            self.timer.stop()

    def selected(self):
        """The selected job's :class:`~instrument.bench.bench_job_handle.JobInfo` (None:
        none; the only one when one runs)."""
        row = self.list.currentRow()
        if 0 <= row < len(self.infos):
            return self.infos[row]
        return self.infos[0] if len(self.infos) == 1 else None

    def others(self) -> list[str]:
        """The running jobs other clients started, named (``job 4 (record) of the
        notebook (pid 812)``), as a close of the window would end them: from the list
        last read (no call to the bench process: asking never waits on it)."""
        service = self.session.service
        if service is None or self.session.lost is not None:
            return []
        mine = getattr(service, "name", None)
        return [i.describe() for i in self.all_infos
                if i.state == "running" and i.owner != mine]

    def confirm(self, title: str, text: str) -> bool:
        """Ask the operator (Yes / No); tests replace this."""
        answer = QMessageBox.question(self, title, text, QMessageBox.StandardButton.Yes
                                      | QMessageBox.StandardButton.No,
                                      QMessageBox.StandardButton.No)
        return answer == QMessageBox.StandardButton.Yes

    def stop_selected(self) -> bool:
        """Stop the selected job after asking (the question names its owner); True if
        it was asked to stop."""
        info = self.selected()
        service = self.session.service
        if info is None or service is None:
            return False
        if not self.confirm("Stop job", f"Stop {info.describe()}? A recording keeps what "
                            "it recorded; a calibration run aborts to the safe state and "
                            "can be resumed."):
            return False
        job = service.job(info.id)
        job.stop()
        job.abort(f"stopped from the window ({getattr(service, 'name', 'the window')})")
        return True
