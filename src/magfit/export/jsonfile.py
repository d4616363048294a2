"""magfit's own format: the lossless JSON of :meth:`magfit.Calibration.to_json` (schema version 1).

It records the schema and its version, the method, the unit, the convention
``corrected = matrix @ (raw - offset)``, the offset, the matrix, the field strength, the number of
samples and ``details`` (the method's options and fit statistics). Floats are written as their
shortest round-trip representation, so :meth:`magfit.Calibration.from_json` gives back an equal
calibration. No conversion, no limits: every calibration can be written.

A non-symmetric matrix (``root="cholesky"``, or a vehicle-frame matrix that includes the
magnetometer-to-vehicle alignment, ``"frame": "vehicle"``) is kept as fitted (the file is lossless) and
the export adds a top-level ``"warnings"`` list saying which rotation it adds to the corrected field;
:meth:`~magfit.Calibration.from_json` ignores that key, so the round trip stays exact.

Several compasses (:func:`magfit.export.export_several`) are a JSON array of these objects, each read
back with :meth:`magfit.Calibration.from_dict`.
"""

from __future__ import annotations

import json
from typing import Any

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
    if rotated_frame_warning(calibration) is None:
        return calibration.to_json() + "\n"
    return json.dumps(write_json_dict(calibration), indent=2, allow_nan=False) + "\n"


def write_json_dict(calibration: Calibration, unit: str | None = None) -> dict[str, Any]:
    """The JSON object of :func:`write_json` as a dict (with its ``"warnings"`` when there are any)."""
    if unit is not None:
        calibration = calibration.with_unit(canonical_name(unit))
    data = calibration.to_dict()
    warning = rotated_frame_warning(calibration)
    if warning is not None:
        data["warnings"] = [warning]
    return data
