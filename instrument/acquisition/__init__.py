"""Taking frames: plans and the plan runner (with its preflight), exposure and
averaging, video recording into a run store (the recorder, its defaults), live
reconstruction of the stream (in this process or its own, through a shared-memory
slot) and the demo on the simulated bench. The old module ``instrument.acquisition``
(now :mod:`instrument.acquisition.exposure`) keeps its names here, imported on first
use.
"""

#: The names of the old module ``instrument.acquisition`` (now :mod:`.exposure`).
_EXPOSURE_NAMES = frozenset(
    {"ExposureError", "ExposureResult", "autoexpose", "average_frames", "full_scale"})


def __getattr__(name: str):
    """A name of the old module ``instrument.acquisition`` (``average_frames``, ...),
    imported from :mod:`instrument.acquisition.exposure` on first use, so that importing
    the room loads nothing."""
    if name in _EXPOSURE_NAMES:
        from . import exposure

        return getattr(exposure, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
