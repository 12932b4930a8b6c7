"""The flags that ``recon``, ``recon3d``, ``recon-run`` and ``capture live`` share, with
one meaning each (docs/cli.md has the table).

``--dark`` takes the same forms everywhere (:func:`recon.options.dark_arg`): ``auto``
(default), ``none``, a level in DN, or a ``calibrate dark`` run or a dark image where
the command can subtract a per-pixel frame; the ``dark_for_*`` functions turn it into
what each reconstruction takes, refusing clearly what it cannot use. The spatially
varying path (``--psf-grid``) uses the plain ``--method``, ``--l1`` and ``--dark``;
its former twins ``--grid-method``, ``--grid-l1`` and ``--grid-dark`` remain as hidden
aliases that print a one-line note (:class:`DeprecatedAlias`).
"""

from __future__ import annotations

import argparse
import sys

from diffuserlab.errors import InputError

__all__ = ["DARK_FORMS", "FRAMES_AUTO", "FRAMES_FRAME", "L1_HELP", "TV_HELP", "DeprecatedAlias",
           "add_dark_option", "add_deprecated", "add_device_option", "check_device",
           "dark_for_grid", "dark_for_image", "dark_for_volume", "grid_method"]

#: ``--tv`` of every reconstruction command.
TV_HELP = ("TV weight in the scaled problem (unitless: unit-sum PSF, raw divided by its "
           "maximum), or auto (default): hold-out cross-validation along a warm-started path")
#: ``--l1`` of every reconstruction command.
L1_HELP = ("l1 weight (sparse scenes) in the scaled problem (unitless), or auto; default 0, "
           "with --psf-grid and --method fista/auto 1e-3 (Eq. 6.2)")

#: ``--dark auto`` and a dark frame in ``recon-run`` and ``capture live`` (the frames' level).
FRAMES_AUTO = ("the simulated camera's offset for a run recorded or a bench run with "
               "--simulate, else with a plain PSF image its dark corner as `recon` does; "
               "a calibrated (dark-subtracted) PSF stack or grid then needs the level")
FRAMES_FRAME = ("or a `calibrate dark` run or a dark image (TIFF, PNG, .npy), subtracted "
                "pixel by pixel (a --psf-grid takes a level)")

#: The help text's description of ``--dark``'s forms (every command).
DARK_FORMS = ("dark level: auto (default; {auto}), none (the inputs are already "
              "dark-subtracted: nothing is subtracted) or a level in DN; {frame}")


def add_dark_option(p, *, auto: str, frame: str) -> None:
    """Add ``--dark`` (type :func:`recon.options.dark_arg`, default ``auto``) to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser or argument group
    auto : str
        What ``auto`` does in this command (for the help text).
    frame : str
        What a dark run or image does here, or that it is refused (for the help text).
    """
    from recon.options import dark_arg

    p.add_argument("--dark", type=dark_arg, default=dark_arg("auto"),
                   metavar="auto|none|DN|DARK_RUN", help=DARK_FORMS.format(auto=auto,
                                                                           frame=frame))


def add_device_option(p) -> None:
    """Add ``--device cpu|cuda|auto`` (default cpu; :func:`recon.backend.resolve_device`)."""
    from recon.options import DEVICES

    p.add_argument("--device", choices=DEVICES, default="cpu",
                   help="where the solver runs: cpu (default; NumPy and numba), cuda (a "
                   "CUDA GPU through CuPy or PyTorch: pip install 'diffuserlab[gpu]'; "
                   "refused with a message when none is usable) or auto (the GPU when one "
                   "is usable, else the CPU); docs/reconstruction.md says what runs there")


def check_device(device: str) -> None:
    """Refuse an unusable ``--device`` before any file is read.

    Raises
    ------
    recon.errors.ReconInputError
        ``cuda`` without CuPy / a CUDA PyTorch, with one that cannot be imported, or
        without a visible device (the message of :func:`recon.backend.resolve_device`;
        exit 2). ``auto`` that falls back to the CPU although a GPU library is
        installed prints why (``diffuserlab: note: ...`` on stderr) and goes on.
    """
    if device == "cpu":
        return
    from recon.backend import resolve_device

    note = resolve_device(device).note
    if note:  # auto on the CPU although a GPU library is installed
        print(f"diffuserlab: note: --device {device}: {note}", file=sys.stderr)


class DeprecatedAlias(argparse.Action):
    """A former spelling of a flag: stores into the new flag's ``dest`` and prints
    ``diffuserlab: note: --OLD is deprecated; use --NEW`` on stderr (hidden from
    ``--help``)."""

    def __init__(self, option_strings, dest, *, replacement: str, **kwargs):
        self.replacement = replacement
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"diffuserlab: note: {option_string} is deprecated; use {self.replacement} "
              "(same meaning)", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_deprecated(p, old: str, new: str, dest: str, **kwargs) -> None:
    """Add ``old`` as a hidden :class:`DeprecatedAlias` of ``new`` (``dest``)."""
    p.add_argument(old, action=DeprecatedAlias, replacement=new, dest=dest,
                   default=argparse.SUPPRESS, **kwargs)


def _refuse_frame(dark, command: str) -> None:
    if dark.path is not None:
        raise InputError(f"--dark {dark}: {command} subtracts one level, not a dark run or "
                         "image; use auto, none or a number (the level in DN, e.g. the mean "
                         "of the dark run's dark_mean product)")


def dark_for_image(dark):
    """``--dark`` for :func:`instrument.reconstruct_files.run_recon`: ``"auto"``,
    ``"none"``, a level (DN) or the dark run's or image's frame, (rows, cols) float32
    (the ``dark`` of :func:`recon.reconstruct`).

    Raises
    ------
    recon.errors.ReconInputError
        A path that is neither a dark run nor a readable image.
    """
    if dark.auto:
        return "auto"
    if dark.none:
        return "none"
    if dark.level is not None:
        return dark.level
    from ..reconstruct_files import dark_level

    return dark_level(dark.path)


def dark_for_volume(dark):
    """``--dark`` for :func:`instrument.reconstruct_files.run_recon3d`: ``"auto"``,
    ``"none"`` or a level (DN).

    Raises
    ------
    diffuserlab.errors.InputError
        A dark run or image (the volume model subtracts one level from stack and raw).
    """
    _refuse_frame(dark, "recon3d")
    return "auto" if dark.auto else "none" if dark.none else dark.level


def dark_for_grid(dark):
    """``--dark`` of a ``--psf-grid`` reconstruction: ``"auto"``, ``"none"`` or the level
    (DN) subtracted from the raw frame (the ``dark`` of :func:`recon.reconstruct`:
    ``auto`` and ``none`` subtract nothing, the grid's PSFs are dark-subtracted and
    ``--background estimate`` fits the frame's offset with the background).

    Raises
    ------
    diffuserlab.errors.InputError
        A dark run or image.
    """
    _refuse_frame(dark, "--psf-grid")
    return dark_for_volume(dark)


def grid_method(method: str, allowed: tuple[str, ...]) -> str:
    """The solver of a ``--psf-grid`` model for ``--method`` (auto: fista).

    Raises
    ------
    diffuserlab.errors.InputError
        A method the command cannot use on a PSF grid.
    """
    if method == "auto":
        return "fista"
    if method not in allowed:
        raise InputError(f"--method {method}: a --psf-grid model is solved with "
                         f"{' or '.join(allowed)} (auto: fista)")
    return method
