"""The ``diffuserlab`` command line.

Subcommands: ``recon`` (one reconstruction from files; the PSF may be one depth of
a run's PSF stack or of a TIFF stack), ``demo`` (the main job: a bench session on
the built-in simulated bench; ``--real-sample`` reconstructs the real DiffuserCam
sample instead), ``recon3d`` (a volume from one image and a PSF stack),
``analyze`` (resolution, similarity, conditioning, grid, field of view of a PSF
stack), ``validate`` / ``devices`` (bench files), ``runs`` (show, export, import
run stores), ``capture live`` / ``capture video`` (live reconstruction, video
recording), ``recon-run`` (batch reconstruction of a recorded run on dask),
``benchmark recon`` (speed vs FFT floor, accuracy, stability,
compressed sensing; 3D speed, memory and accuracy), ``holo evaluate`` / ``holo
benchmark`` (Table 7.1, hologram speed), plus the commands other layers register
under the entry-point group ``diffuserlab.commands`` (``calibrate`` and ``align``
from calibration_routines). Bad input, and the ordinary OS errors (permission denied,
no such file, no space left, ...), exit with status 2 and a one-line reason; a
diverging solver exits with status 3; any other exception is a bug: one line and
status 1, or its traceback with ``--debug``.

Every command module has ``add_subcommands(sub)``; its parsers carry
``handler=FUNCTION`` (and, where a command maps more than the project's input
errors to status 2, ``input_errors=(...)``). :func:`main` dispatches once to
``args.handler(args)`` inside one error boundary. Library code logs; :func:`main`
sends INFO records (DEBUG with ``-v``) to the console, and only this package prints.
"""

from __future__ import annotations

# the first line of the package: Ctrl-C while the handlers are imported (Python's own
# KeyboardInterrupt) or while the command modules pull in numpy, scipy, zarr (seconds)
try:
    import sys

    from . import startup_signals as _startup_signals

    # the command process: every signal from here on is one line (the first raises
    # here; one after it, or after the imports, is held for main)
    _startup_signals.install(starting=True)
    import argparse
    import errno
    import logging
    import signal
    import warnings

    from diffuserlab.errors import DiffuserLabError

    from . import (
        analyze,
        bench,
        benchmark,
        capture,
        demo,
        holo,
        recon,
        recon3d,
        recon_run,
        runs,
    )

    # below, up to main's boundary, an interrupt would escape with a traceback: held
    _startup_signals.hold()
except KeyboardInterrupt as _exc:  # one line and 128 + the signal; nothing has run yet
    # (nothing imported here: the interrupt may have come in any module's import)
    import sys

    sys.stderr.write(f"diffuserlab: interrupted ({str(_exc) or 'Ctrl-C'}) while starting; "
                     "nothing was done\n")  # a Terminated names its signal
    if "_startup_signals" in globals():  # the status below, not exit -2 under python -m
        _startup_signals.forget_unhandled_interrupt()
    raise SystemExit(128 + getattr(_exc, "signum", 2)) from None  # 2: SIGINT

__all__ = ["build_parser", "main", "os_error_line", "run_handler"]

log = logging.getLogger("diffuserlab")

#: The command modules, in the order of ``diffuserlab --help``.
COMMANDS = (recon, demo, recon3d, analyze, bench, runs, capture, recon_run, benchmark, holo)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors (unknown option, a value of the wrong type,
    a missing argument) are one line ``diffuserlab: error: ...`` and exit status 2, like
    every other bad input; ``--help`` still shows the usage. Subparsers inherit it."""

    def error(self, message: str) -> None:
        command = self.prog.removeprefix("diffuserlab").strip()
        where = f"{command}: " if command else ""
        self.exit(2, f"diffuserlab: error: {where}{_one_line(message)} (see {self.prog} "
                  "--help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of ``diffuserlab`` (documented in the README).

    Returns
    -------
    argparse.ArgumentParser
        Every subcommand's parser sets ``handler`` (see the module docstring); the
        commands of the ``diffuserlab.commands`` entry points are added last.
    """
    parser = _Parser(
        prog="diffuserlab",
        description="Bench control, calibration and reconstruction for lensless diffuser "
        "cameras and random-mask holographic displays (Kuo 2020). Bad input: one line, "
        "exit status 2; a diverging solver: exit status 3; a bug: one line, exit status 1 "
        "(--debug shows the traceback). Outputs never replace inputs, nor existing files "
        "without --overwrite.")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="debug logging, other libraries' log records included")
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an unexpected error (a bug) instead of "
                        "one line")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_subcommands(sub)
    for add in _plugin_commands():
        add(sub)
    return parser


def _plugin_commands():
    """``add_subcommands(sub)`` functions registered under ``diffuserlab.commands``
    (packages above this layer, e.g. calibration_routines, add their commands so)."""
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group="diffuserlab.commands"), key=lambda e: e.name):
        try:
            yield ep.load()
        except ImportError as exc:  # a broken plugin must not take the CLI down
            log.warning("command plugin %s not loaded: %s", ep.name, exc)


#: Top-level packages whose log records reach the console without ``-v``.
_PACKAGES = frozenset({"diffuserlab", "recon", "drivers", "instrument",
                       "calibration_routines", "gui"})


def _project_record(record: logging.LogRecord) -> bool:
    """Console filter: a record of ours. Other libraries' records (tifffile's "invalid
    page offset" of a truncated file, ...) would add lines to the one-line error of
    bad input; ``-v`` shows them."""
    return record.name.partition(".")[0] in _PACKAGES


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def os_error_line(exc: OSError) -> str:
    """``REASON: PATH`` of an OSError (both paths of a rename); a disk that is full gets
    its free space."""
    from ..writer.guards import checked_outputs

    reason = exc.strerror or _one_line(exc) or type(exc).__name__
    paths = [p for p in (exc.filename, exc.filename2) if p is not None]
    line = f"{reason}: {' -> '.join(map(str, paths))}" if paths else reason
    if not paths and checked_outputs():  # e.g. zarr's write on a full disk names no file
        paths = checked_outputs()[-1:]
        line = f"{reason} while writing {', '.join(checked_outputs())}"
    if exc.errno in (errno.ENOSPC, errno.EDQUOT) and paths and "free" not in line:
        from ..atomic import free_space_text

        line += f" ({free_space_text(paths[0])})"
    return line


def _memory_line(exc: MemoryError) -> str:
    """One line for a MemoryError: what failed to allocate and what the machine has."""
    import os

    what = _one_line(exc) or "an allocation failed"
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
        free = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES") / 2 ** 30
        have = f"; this machine has {total:.1f} GiB of memory, {free:.1f} GiB free"
    except (ValueError, OSError, AttributeError):
        have = ""
    return f"out of memory: {what}{have}; give smaller sizes"


def _inputs_note(args: argparse.Namespace, exc: BaseException) -> str:
    """`` (in one of: a.tif, b.tif, out/r)`` (the command's paths) for a message of a
    library outside the project (numpy's "operands could not be broadcast ...",
    "could not convert string to float: 'abc'") that names neither a file nor an
    option of the command; empty for the project's own messages, which name what
    they refuse."""
    from diffuserlab.errors import InputError

    text = str(exc)
    if isinstance(exc, InputError) or "--" in text:
        return ""
    given = {k: v for k, v in vars(args).items() if isinstance(v, str) and v
             and k not in ("handler", "command") and ("/" in v or "." in v)}
    if not given or any(v in text for v in given.values()):
        return ""
    return f" (in one of: {', '.join(given.values())})"


def _warning_as_log_record(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` of the command line: a Python warning becomes one DEBUG
    record (``-v`` shows it), never a source line on the console. The project's own
    warnings (saturation, ...) are logged by the library as one WARNING record each,
    so the console shows each once."""
    log.debug("%s: %s (%s:%s)", category.__name__, message, filename, lineno)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``diffuserlab`` console script; returns the exit status.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        The handler's status; 2 (one line on stderr) on
        :class:`diffuserlab.errors.InputError` (the project's input errors:
        :class:`recon.errors.ReconInputError`,
        :class:`instrument.runs.runstore.RunStoreError`,
        :class:`instrument.acquisition.plan.PlanError`,
        :class:`instrument.writer.guards.OutputError`,
        :class:`instrument.devices.bench_file.MissingBenchFile`, ...) and the errors a command
        lists in ``input_errors`` (no command turns every ValueError into bad input:
        an unexpected one is a bug); 2 and one line per problem on
        :class:`instrument.config.BenchConfigError`; 3 when a solver diverged
        (:class:`recon.errors.DivergenceError`); 2 (one line) on a refused device
        setting or a missing driver library (:class:`drivers.errors.DeviceValueError`,
        :class:`~drivers.errors.MissingDependencyError`) and 1 (one line) on any other
        device error (a timeout, a disconnect: the bench failed, not the input); 2 (one
        line naming the device) when a device cannot be opened
        (:class:`instrument.devices.bench_setup.BenchOpenError`); 2 (one line naming the path)
        on every OS error (permission denied, no such file, no space left with the free
        space, read-only file system, I/O error, ...), 2 on a MemoryError (what failed
        to allocate, the machine's memory) and an OverflowError; 130 on Ctrl-C, 143 on
        SIGTERM and 129 on SIGHUP, which are handled like Ctrl-C
        (:mod:`instrument.cli.interrupts`: runs aborted or stopped, locks released),
        from the package's first line on (before the command runs: one line
        ``interrupted (...) while starting; nothing was done``);
        1 and one line saying it is a bug on any other exception, whose traceback
        ``--debug`` shows instead.
    """
    from diffuserlab.errors import InputError

    from .interrupts import after_the_command, exit_status, signal_text, terminate_like_ctrl_c

    # the signals of this call (the command process: since its first line)
    mark = 0 if _startup_signals.is_command_process() else _startup_signals.count()
    chosen: list[int] = []  # the command's status, once chosen
    try:
        try:  # up to the command's error boundary, nothing is done
            _startup_signals.release()  # a signal held since the imports is raised here
            args = build_parser().parse_args(argv)
            _console(args)  # from here a swallowed interrupt is sent again (quiet_shutdown)
            # an import caught the interrupt, or a finalizer did (startup_signals, quiet)
            swallowed = _startup_signals.received(mark)
            input_errors = (InputError, *getattr(args, "input_errors", ()))
        except KeyboardInterrupt as exc:  # Ctrl-C (SIGTERM, SIGHUP) while the modules load
            # or the console is set up
            swallowed = getattr(exc, "signum", None) or _startup_signals.received(mark) \
                or signal.SIGINT
        if swallowed is not None:
            print(f"diffuserlab: interrupted ({signal_text(swallowed)}) while starting; "
                  "nothing was done", file=sys.stderr)
            chosen.append(128 + int(swallowed))
        else:
            with terminate_like_ctrl_c() as received, warnings.catch_warnings():
                warnings.showwarning = _warning_as_log_record
                status = _dispatch(args, input_errors, _startup_signals.count())
            if received and status == exit_status(KeyboardInterrupt()):
                status = 128 + received[0]  # a handler's own Ctrl-C status, for SIGTERM/SIGHUP
            chosen.append(status)
    except KeyboardInterrupt as exc:  # as the error boundary is entered or left (the
        # command's own interrupts end inside it)
        if not chosen:  # once chosen, the status stands
            print(f"diffuserlab: interrupted ({signal_text(getattr(exc, 'signum', None))})",
                  file=sys.stderr)
            chosen.append(exit_status(exc))
    after_the_command()  # the command process: a signal while Python exits changes nothing
    return chosen[0]


def _console(args: argparse.Namespace) -> None:
    """Before a command: the exit hooks quiet
    (:func:`instrument.cli.interrupts.quiet_shutdown`), the console's log records (INFO,
    DEBUG with ``-v``; other libraries' only with ``-v``) and the outputs' record reset."""
    from ..writer.guards import checked_outputs
    from .interrupts import quiet_shutdown

    quiet_shutdown(args.debug)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    for handler in logging.getLogger().handlers:
        if args.verbose:
            handler.removeFilter(_project_record)
        elif _project_record not in handler.filters:
            handler.addFilter(_project_record)
    checked_outputs(reset=True)


def run_handler(args: argparse.Namespace) -> int:
    """Run ``args.handler(args)`` inside the error boundary of :func:`main` (the same
    exit statuses and one-line messages), for a command parsed by its own parser: the
    studies of the repository's ``benchmarks/``, which are not ``diffuserlab``
    subcommands.

    Parameters
    ----------
    args : argparse.Namespace
        With ``handler`` (called with ``args``, returns the status or None) and
        ``debug`` (True: a bug raises with its traceback); ``input_errors``, if
        present, adds exception classes reported as bad input.

    Returns
    -------
    int
        The handler's status, or the boundary's (see :func:`main`).
    """
    from diffuserlab.errors import InputError

    return _dispatch(args, (InputError, *getattr(args, "input_errors", ())))


class _NeverRaised(DiffuserLabError):
    """Stands for an exception class whose module the command never imported (never
    raised)."""


def _raised_class(module: str, name: str) -> type[BaseException]:
    """The exception class ``module.name`` when the command imported ``module``, else
    :class:`_NeverRaised`: a module never imported raised nothing, and importing it
    only to catch its error would load pydantic (the bench models) into commands
    that never read a bench file (``runs show``, ``recon``, ...)."""
    loaded = sys.modules.get(module)
    return _NeverRaised if loaded is None else getattr(loaded, name)


def _dispatch(args: argparse.Namespace, input_errors: tuple, mark: int = 0) -> int:
    """Run ``args.handler`` inside the error boundary of :func:`main`; its status
    (``mark``: the signals seen before it, :func:`startup_signals.count`)."""
    from drivers.errors import DeviceError, DeviceValueError, MissingDependencyError
    from recon.errors import DivergenceError

    from .interrupts import exit_status, signal_text

    # the bench's error classes are looked up when an exception reaches their clause
    # (an except clause's expression is evaluated then), after the handler ran
    try:
        return int(args.handler(args) or 0)
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP not handled by the command
        print(f"diffuserlab: interrupted ({str(exc) or 'Ctrl-C'})", file=sys.stderr)
        return exit_status(exc)
    except _raised_class("instrument.devices.bench_setup", "BenchOpenError") as exc:  # a device
        # missing or unplugged: the bench, not a bug
        fix = ("fix that value in the bench file (diffuserlab validate BENCH.toml lists every "
               "problem)" if isinstance(exc.__cause__, DeviceValueError) else
               "check that the device is connected and powered (diffuserlab devices "
               "BENCH.toml), or use --simulate")
        print(f"diffuserlab: error: cannot open the bench: {_one_line(exc)}; {fix}",
              file=sys.stderr)
        return 2
    except _raised_class("instrument.config.problems", "BenchConfigError") as exc:  # one
        # line per problem of the bench file
        for line in exc.lines():
            print(f"diffuserlab: error: {line}", file=sys.stderr)
        return 2
    except DivergenceError as exc:
        print(f"diffuserlab: diverged: {(str(exc).splitlines() or [''])[0]}", file=sys.stderr)
        return 3
    except input_errors as exc:
        print(f"diffuserlab: error: {_one_line(exc)}{_inputs_note(args, exc)}",
              file=sys.stderr)
        return 2
    except DeviceError as exc:  # a refused value or a missing library is the input's
        bad_input = isinstance(exc, DeviceValueError | MissingDependencyError)
        print(f"diffuserlab: {'error' if bad_input else 'device error'}: {_one_line(exc)}",
              file=sys.stderr)
        return 2 if bad_input else 1
    except Exception as exc:
        signum = _startup_signals.received(mark)
        if signum is not None and not args.debug:  # a library turned the interrupt into
            # an error of its own (dask: "Nanny failed to start")
            print(f"diffuserlab: interrupted ({signal_text(signum)})", file=sys.stderr)
            return 128 + signum
        if args.debug:
            raise
        if isinstance(exc, OSError):  # the system's or the user's problem, not a bug
            print(f"diffuserlab: error: {os_error_line(exc)}", file=sys.stderr)
            return 2
        if isinstance(exc, MemoryError):
            print(f"diffuserlab: error: {_memory_line(exc)}", file=sys.stderr)
            return 2
        if isinstance(exc, OverflowError):
            print(f"diffuserlab: error: a number is too large ({_one_line(exc)}); give "
                  "smaller values", file=sys.stderr)
            return 2
        # any other exception is a bug: one line, never a traceback
        print(f"diffuserlab: internal error (a bug): {type(exc).__name__}: {_one_line(exc)}; "
              "re-run with --debug for the traceback and report it", file=sys.stderr)
        return 1
