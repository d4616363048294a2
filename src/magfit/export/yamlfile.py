"""A generic YAML file: offset, matrix and field strength with magfit's convention, for any consumer.

For ROS nodes and scripts that apply a full calibration themselves (a ``sensor_msgs/MagneticField``
republisher, a launch file's parameters)::

    magnetometer_calibration:
      convention: corrected = matrix @ (raw - offset)
      unit: uT                 # of offset, field_strength and the raw samples
      offset: [x, y, z]
      matrix: [[..], [..], [..]]   # row-major: matrix[i][j] is row i, column j
      field_strength: B

The values keep the samples' unit (no conversion; raw counts are fine) and are written as the
shortest text that reads back the same double (``repr``) with a decimal point always in the mantissa
(``3.0e-05``, not ``3e-05``, which YAML 1.1 readers such as PyYAML and ROS 1's ``rosparam`` take for a
string: :func:`._common.yaml_float`), so every YAML reader gets magfit's numbers exactly. A
non-symmetric matrix (``root="cholesky"``) is written as fitted, with the warning of
:func:`._common.rotated_frame_warning` in a comment. Every calibration can be written.
"""

from __future__ import annotations

import json

from ..calibration import CONVENTION, Calibration
from ._common import describe, label_unit, plain, rotated_frame_warning, yaml_float

KEY = "magnetometer_calibration"


def _number(value: float) -> str:
    return yaml_float(value)


def write_yaml(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as a YAML mapping under ``magnetometer_calibration`` (see the module docstring).

    Raises
    ------
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    label = label_unit(calibration, unit)
    lines = [
        "# magfit magnetometer calibration. Generated file: re-export instead of editing.",
        *(f"# {plain(line)}" for line in describe(calibration, label)),
    ]
    warning = rotated_frame_warning(calibration)
    if warning:
        lines.append(f"# {plain(warning)}")
    rows = ", ".join("[" + ", ".join(_number(v) for v in row) + "]" for row in calibration.matrix)
    lines += [
        f"{KEY}:",
        # JSON strings are YAML double-quoted scalars: safe whatever the method's name holds.
        f"  convention: {json.dumps(CONVENTION)}",
        f"  unit: {json.dumps(label)}",
        f"  method: {json.dumps(calibration.method)}",
        f"  offset: [{', '.join(_number(v) for v in calibration.offset)}]",
        f"  matrix: [{rows}]",
        f"  field_strength: {_number(calibration.field_strength)}",
    ]
    return "\n".join(lines) + "\n"
