"""The typed parameter models of the bench layer: :class:`diffuserlab.options.Options`
and :func:`~diffuserlab.options.option`, declared once in layer 0 so that the
reconstruction layer declares its own parameters (:class:`recon.options.ReconOptions`)
with the same machinery. Re-exported here for the calibration routines' models
(:mod:`calibration_routines.parameters`)."""

from diffuserlab.options import Options, OptionSpec, option

__all__ = ["OptionSpec", "Options", "option"]
