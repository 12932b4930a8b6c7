"""The typed parameter models of the bench layer and the tables of which fields each
front end offers, declared here, outside the command line, so the command line and the
GUI's forms take them from one place (standard library and layer 0 only: the command
line's start imports this module).

- :class:`diffuserlab.options.Options` and :func:`~diffuserlab.options.option`, declared
  once in layer 0 so that the reconstruction layer declares its own parameters
  (:class:`recon.options.ReconOptions`) with the same machinery; re-exported here for
  the calibration routines' models (:mod:`calibration_routines.parameters`);
- :data:`COMMAND_FIELDS` and :data:`GRID_FIELDS`: the reconstruction fields each
  command offers (its flags, ``instrument.cli.recon_flags``) and each GUI form shows;
- :class:`RunOptions`: ``recon-run``'s own options, the command's and the GUI's Batch
  form's;
- :func:`check_pitch_um`: the one check of a sensor pixel pitch, the commands' and
  :func:`instrument.runs.stacks.import_psf_stack`'s.
"""

from __future__ import annotations

from diffuserlab.options import Options, OptionSpec, option

__all__ = ["COMMAND_FIELDS", "GRID_FIELDS", "OptionSpec", "Options", "RunOptions",
           "check_pitch_um", "option"]

#: The :class:`recon.options.ReconOptions` fields each command offers as flags, in
#: ``--help`` order (the ``--psf-grid`` group's model, pca-k, background and two-part
#: are added by ``instrument.cli.grid_options.add_grid_options``), and the
#: :class:`recon.options.LiveOptions` of ``capture live``.
COMMAND_FIELDS = {
    "recon": ("method", "iterations", "seconds", "bin_factor", "tv", "prior", "l1", "erase",
              "seed", "full_scale", "dark", "allow_mixed_ranges", "device", "early_stop"),
    "recon3d": ("method", "iterations", "tv", "prior", "empty_planes", "l1", "bin_factor",
                "dark", "allow_mixed_ranges", "device"),
    "recon-run": ("method", "iterations", "tv", "prior", "l1", "bin_factor", "dark", "device",
                  "early_stop"),
    "capture live": ("dark", "device", "bin_factor"),
}
#: The ``--psf-grid`` fields of each command (``instrument.cli.grid_options.add_grid_options``).
GRID_FIELDS = {"recon": ("model", "k", "background", "two_part"),
               "recon3d": ("model", "k", "background"),
               "recon-run": ("model", "k", "background")}


class RunOptions(Options):
    """``recon-run``'s own options (the run's PSF, frames, workers, products); its
    reconstruction flags are :class:`recon.options.ReconOptions`'. The command's parser
    and the GUI's Batch form (:func:`gui.jobs.batch_reconstruct`) are generated from
    both."""

    command = "recon-run"

    psf: str | None = option(
        None, help="PSF image, or a PSF stack (a run store or TIFF stack) with --depth (or "
        "--psf-grid instead)", default_text="none", label="PSF")
    depth_mm: float | None = option(
        None, help="depth of the stack's PSF to use (nearest plane within 5 %)", unit="mm",
        flag="--depth", default_text="a plain PSF image", label="depth")
    psf_product: str = option(
        "psf_stack", help="which stack of a calibration run: psf_stack or psf_stack_raw",
        label="PSF product")
    frames: str | None = option(
        None, help="frames A:B to reconstruct (a damaged frame is left out and listed)",
        default_text="every stored frame", label="frames")
    workers: int | None = option(
        None, help="local dask worker processes (at most the machine's cores, and one per "
        "frame)", default_text="one per core", label="workers")
    scheduler: str | None = option(
        None, help="address of a dask.distributed scheduler (tcp://host:8786); its workers "
        "must see the run's path", default_text="local workers", label="scheduler")
    dff: float | None = option(
        None, help="also store ΔF/F against this per-pixel percentile baseline (e.g. 20)",
        metavar="PERCENTILE", default_text="none", label="ΔF/F percentile")
    product: str | None = option(
        None, help="name of the product", default_text="recon_<method>", label="product")
    overwrite: bool = option(
        False, help="replace a product of that name made with other settings")

    @classmethod
    def check_together(cls, values, *, front: str = "cli") -> None:
        """Local workers and a scheduler's address exclude each other (the command
        line's mutually exclusive group; the GUI's forms take the check from here).

        Raises
        ------
        diffuserlab.errors.InputError
            Both given (the message names both and the fix).
        """
        from diffuserlab.errors import InputError

        if values.get("workers") is not None and values.get("scheduler") is not None:
            workers, scheduler = cls.spec("workers"), cls.spec("scheduler")
            raise InputError(
                f"{workers.name(front)}: not allowed with {scheduler.name(front)}; give "
                "local workers or a scheduler's address, not both")


def check_pitch_um(pitch_um: float | None, option: str = "--pitch-um") -> float | None:
    """The sensor pixel pitch an option gives, um, checked: the one check of ``recon``,
    ``recon3d``, ``analyze``, ``runs import-psf`` and
    :func:`instrument.runs.stacks.import_psf_stack` (it becomes an OME pixel size).

    Parameters
    ----------
    pitch_um : float or None
        As parsed (``type=float``: ``inf``, ``1e400`` and ``nan`` parse) or given;
        None: not given (no pixel size, or the PSF run's).
    option : str
        The option, for the message: a flag (``--pitch-um``, shown ``--pitch-um inf``)
        or a Python keyword (``pitch_um``, shown ``pitch_um=inf``).

    Returns
    -------
    float or None
        ``pitch_um``.

    Raises
    ------
    diffuserlab.errors.InputError
        Not a finite number > 0 (0 names leaving the option out for no pixel size).
    """
    import math
    import numbers

    from diffuserlab.errors import InputError

    if pitch_um is None:
        return None
    sep = " " if option.startswith("-") else "="
    if isinstance(pitch_um, bool) or not isinstance(pitch_um, numbers.Real):
        raise InputError(f"{option}{sep}{pitch_um!r}: give the sensor's pixel pitch in "
                         f"micrometres, a finite number > 0 (e.g. {option}{sep}3.45)")
    if pitch_um == 0:
        raise InputError(f"{option}{sep}0: a pixel pitch is > 0; leave {option} out for no "
                         "pixel size (or the PSF run's)")
    if not (math.isfinite(pitch_um) and pitch_um > 0):
        raise InputError(f"{option}{sep}{pitch_um:g}: give the sensor's pixel pitch in "
                         f"micrometres, a finite number > 0 (e.g. {option}{sep}3.45)")
    return float(pitch_um)
