"""Operator GUI (layer 5, PySide6 + pyqtgraph; install the ``gui`` extra).

May import ``instrument``, ``calibration_routines`` and ``recon``.
"""
