"""The flags that ``recon``, ``recon3d``, ``recon-run`` and ``capture live`` share, with
one meaning each, generated from their one declaration,
:class:`recon.options.ReconOptions` (:func:`add_recon_flags`; docs/cli.md's table is
:func:`flags_table`, ``python -m instrument.cli.recon_flags`` prints it).

``--dark`` takes the same forms everywhere (:func:`recon.options.dark_arg`): ``auto``
(default), ``none``, a level in DN, or a ``calibrate dark`` run or a dark image,
subtracted pixel by pixel, with one meaning of ``auto`` in every command
(:func:`instrument.processing.reconstruct_files.resolve_dark`); :func:`dark_for_grid` refuses
what a PSF grid cannot use (a frame). The spatially
varying path (``--psf-grid``) uses the plain ``--method``, ``--l1`` and ``--dark``;
its former twins ``--grid-method``, ``--grid-l1`` and ``--grid-dark`` remain as hidden
aliases that print a one-line note (:class:`DeprecatedAlias`).
"""

from __future__ import annotations

import argparse
import sys

from diffuserlab.errors import InputError

from ..options import COMMAND_FIELDS, GRID_FIELDS

__all__ = ["DeprecatedAlias", "add_deprecated", "add_device_option",
           "add_recon_flags", "check_device", "check_recon_flags", "dark_for_grid",
           "flags_table", "grid_method"]

#: What a command shows more narrowly than the declaration (the default stays):
#: recon3d checks its method itself (``unknown method 'gd'; choose admm or fista``).
_NARROWER = {"recon3d": {"method": {"choices": None, "metavar": "{auto,admm,fista}"}}}


def add_recon_flags(p, command: str, *, fields: tuple[str, ...] | None = None) -> None:
    """Add ``command``'s reconstruction flags to ``p``, generated from
    :class:`recon.options.ReconOptions` (flag, type, default, limits, help).

    Parameters
    ----------
    p : argparse.ArgumentParser or argument group
    command : str
        A key of :data:`COMMAND_FIELDS`.
    fields : tuple of str, optional
        Only these (default: the command's :data:`COMMAND_FIELDS`).
    """
    from recon.options import ReconOptions

    ReconOptions.add_arguments(p, fields=fields or COMMAND_FIELDS[command],
                               overrides=_NARROWER.get(command))


def check_recon_flags(args):
    """The parsed reconstruction flags, validated against their declarations before any
    file is read (limits, types); the message names the flag (``--tv``).

    Returns
    -------
    recon.options.ReconOptions
        What the runners take (:func:`instrument.processing.reconstruct_files.run_recon`, ...).

    Raises
    ------
    diffuserlab.errors.InputError
        A value outside its limits (``--iterations 0``, ``--tv -1``, ``--erase 1``).
    """
    from recon.options import ReconOptions

    return ReconOptions.from_namespace(args)


def add_device_option(p) -> None:
    """Add ``--device cpu|cuda|auto`` (:class:`recon.options.ReconOptions`'s ``device``;
    :func:`recon.backend.resolve_device`)."""
    from recon.options import ReconOptions

    ReconOptions.add_arguments(p, fields=("device",))


def flags_table() -> str:
    """docs/cli.md's table of the reconstruction flags: every
    :class:`recon.options.ReconOptions` and :class:`recon.options.LiveOptions` field
    with the commands that offer it (generated; ``python -m instrument.cli.recon_flags``
    prints it)."""
    from recon.options import LiveOptions, ReconOptions

    commands: dict[str, list[str]] = {}
    for command, fields in COMMAND_FIELDS.items():
        for f in (*fields, *GRID_FIELDS.get(command, ())):
            commands.setdefault(f, []).append(command)
    lines = ReconOptions.markdown().splitlines()
    out = [lines[0] + " commands |", lines[1] + "---|"]
    for s, row in zip(ReconOptions.specs(), lines[2:], strict=True):
        out.append(row + f" {', '.join(commands.get(s.dest, ['Python only']))} |")
    for s, row in zip(LiveOptions.specs(), LiveOptions.markdown().splitlines()[2:],
                      strict=True):
        flag = "`--method` (live)" if s.dest == "method" else "`--method admm:K` (K)"
        out.append(row.replace(f"`{s.flag}`", flag, 1) + " capture live |")
    return "\n".join(out)


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
    return "auto" if dark.auto else "none" if dark.none else dark.level


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


if __name__ == "__main__":  # docs/cli.md's table
    print(flags_table())
