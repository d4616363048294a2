"""magfit's own format: the lossless JSON of :meth:`magfit.Calibration.to_json` (schema version 1).

It records the schema and its version, the method, the unit, the convention
``corrected = matrix @ (raw - offset)``, the offset, the matrix, the field strength, the number of
samples and ``details`` (the method's options and fit statistics). Floats are written as their
shortest round-trip representation, so :meth:`magfit.Calibration.from_json` gives back an equal
calibration. No conversion, no limits: every calibration can be written.

A non-symmetric matrix (``root="cholesky"``) is kept as fitted (the file is lossless) and the
export adds a top-level ``"warnings"`` list saying which rotation it adds to the corrected field;
:meth:`~magfit.Calibration.from_json` ignores that key, so the round trip stays exact.
"""

from __future__ import annotations

import json

from ..calibration import Calibration
from ..units import canonical_name
from ._common import rotated_frame_warning


def write_json(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as magfit JSON; ``unit`` (canonicalised, e.g. ``"µT"`` -> ``"uT"``) replaces the recorded unit.

    Raises
    ------
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    if unit is not None:
        calibration = calibration.with_unit(canonical_name(unit))
    warning = rotated_frame_warning(calibration)
    if warning is None:
        return calibration.to_json() + "\n"
    data = calibration.to_dict()
    data["warnings"] = [warning]
    return json.dumps(data, indent=2, allow_nan=False) + "\n"
