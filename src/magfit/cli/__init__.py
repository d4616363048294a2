"""The ``magfit`` command line.

Each command lives in its own module and is a thin layer: parse the options, call the library, print.
Library errors are caught only here, at the boundary (:class:`MagfitGroup`), and turned into one line on
stderr and an exit status:

- 0: success;
- 1: a fit failed on the data (:class:`~magfit.CalibrationError`), or ``compare`` found a file on which
  every method failed;
- 2: a usage or input error (bad option, unreadable file, malformed samples, refused output path);
- 3: an unexpected error (a bug: rerun with ``--debug`` for the traceback and report it);
- 141 (128 + SIGPIPE), quietly, when the reader of standard output closes it (``magfit apply ... -o - | head``);
- 130 on Ctrl-C (SIGINT), 128 + the signal number on SIGTERM (143) or SIGHUP (129): the command stops,
  its temporary files are removed and no output is left half-written (docs/reliability.md).

``magfit --debug <command>`` lets every error through with its traceback.

Importing :mod:`magfit` never imports this package (click and rich are the ``cli`` extra).
"""

from .app import MagfitGroup, cli, main

__all__ = ["MagfitGroup", "cli", "main"]
