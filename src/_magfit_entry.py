"""The ``magfit`` command's entry point, under a name that no script in ``bin/`` takes.

pymavlink, which MAVProxy and most ArduPilot tooling install, puts its own script ``magfit.py`` (and
``magfit_*.py``) in the same ``bin/`` folder as the ``magfit`` command. Python runs a script with the
script's folder first on ``sys.path``, so ``import magfit`` from ``bin/magfit`` would find that script
instead of this package, and run pymavlink's offset fit. This module imports nothing of magfit until
:func:`main` has taken every such folder off ``sys.path``.
"""

from __future__ import annotations

import os
import sys

__all__ = ["main"]


def _shadows(entry: str) -> bool:
    """Whether ``import magfit`` would find a plain ``magfit.py`` in this ``sys.path`` entry.

    A folder that holds the package itself (``magfit/__init__.py``, found before a module of the same name)
    shadows nothing.
    """
    folder = entry or os.getcwd()
    return os.path.isfile(os.path.join(folder, "magfit.py")) and not os.path.isfile(
        os.path.join(folder, "magfit", "__init__.py")
    )


def main() -> int:
    """Run the ``magfit`` command line (:func:`magfit.cli.main`) and return its exit status."""
    if "magfit" not in sys.modules:
        sys.path[:] = [entry for entry in sys.path if not _shadows(entry)]
    from magfit.cli import main as run

    return run()
