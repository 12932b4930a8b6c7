"""The GUI's panels, one per device or task (see docs/architecture.md, "... a GUI panel").

Each panel is a Qt widget that calls library functions on workers
(:class:`gui.workers.Job`) and holds no logic of its own. Images are shown
row-major (``(rows, cols)`` as the camera and the reconstructions store them).
"""

import pyqtgraph as pg

pg.setConfigOptions(imageAxisOrder="row-major")
