"""ArduPilot compass parameters (``.param``): COMPASS_OFS_*, COMPASS_DIA_*, COMPASS_ODI_*, COMPASS_SCALE.

ArduPilot's convention, from ``AP_Compass_Backend::correct_field`` (libraries/AP_Compass), applied
to every sample in milligauss, in the body frame (after COMPASS_ORIENT / AHRS_ORIENTATION)::

    mag += (OFS_X, OFS_Y, OFS_Z)                  # offsets are ADDED
    mag *= SCALE                                  # only when 0.85 <= SCALE <= 1.4 (have_scale_factor)
    mag  = [[DIA_X, ODI_X, ODI_Y],
            [ODI_X, DIA_Y, ODI_Z],
            [ODI_Y, ODI_Z, DIA_Z]] @ mag          # a SYMMETRIC matrix

magfit's ``corrected = matrix @ (raw - offset)`` (paper eq. 5) maps onto it with ``k`` the factor
from the samples' unit to milligauss (10 for µT, 1000 for gauss)::

    OFS = -k * offset      DIA = diag(matrix)      ODI = (matrix[0,1], matrix[0,2], matrix[1,2])
    SCALE = 1

so ArduPilot's corrected field is ``k`` times magfit's. SCALE = 1 is a no-op inside ArduPilot's
accepted range: magfit's field is already in physical milligauss (a physical unit is required), so
no further scaling is wanted; if the local field strength B is known (World Magnetic Model), set
SCALE = B / field_strength by hand, as ArduPilot's own calibrator does. A Cholesky-root matrix is
replaced by its symmetric root (same ellipsoid, see :func:`._common.symmetric_matrix`).

Refused, rather than written wrong (ArduPilot would reject, ignore or fail to arm):

- no unit or raw counts: ArduPilot needs milligauss;
- ``|OFS| > 1800`` mG: the arming check fails when the offset length exceeds COMPASS_OFFS_MAX
  (default 1800, AP_Compass.cpp) and the calibrator rejects any axis beyond it;
- a diagonal outside (0.2, 5) or an off-diagonal with ``|ODI| >= 1``: outside what
  ``CompassCalibrator::fit_acceptable`` accepts;
- a field strength outside [185, 875] mG: the arming check "Check mag field"
  (AP_ARMING_COMPASS_MAGFIELD_MIN/MAX, 0.35 and 1.65 x 530 mG) fails; usually a wrong unit;
- a non-symmetric matrix other than a Cholesky root.

Written with a ``# WARNING`` line: an offset axis beyond +-400 mG, the ``@Range`` of COMPASS_OFS_*
in AP_Compass.cpp's parameter documentation. ArduPilot itself accepts it, but Mission Planner checks
the documented range when a value is loaded or edited (ConfigRawParams.cs) and asks "COMPASS_OFS_X
value is out of range. Do you want to continue?"; answering No keeps the old value.

The file uses Mission Planner's ``NAME,VALUE`` lines (MAVProxy's ``param load`` reads them too),
``#`` comments, and writes the first compass only (COMPASS_OFS2_* ... for the others).
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError
from ._common import describe, factor, float32_text, physical_unit, plain, symmetric_matrix

#: COMPASS_OFFS_MAX default (AP_COMPASS_OFFSETS_MAX_DEFAULT), mG: arming fails when |COMPASS_OFS| exceeds it.
OFFSET_MAX_MG = 1800.0
#: The documented @Range of COMPASS_OFS_* (mG); Mission Planner asks before loading a value outside it.
OFFSET_RANGE_MG = 400.0
#: CompassCalibrator::fit_acceptable: 0.2 < DIA < 5.0 (exclusive).
DIAGONAL_RANGE = (0.2, 5.0)
#: CompassCalibrator::fit_acceptable: |ODI| < 1.0.
OFFDIAGONAL_MAX = 1.0
#: AP_Arming "Check mag field": 185 <= |field| <= 875 mG.
FIELD_RANGE_MG = (185.0, 875.0)
#: COMPASS_MIN/MAX_SCALE_FACTOR (CompassCalibrator.h): outside, Compass::have_scale_factor() ignores SCALE.
SCALE_RANGE = (0.85, 1.4)
#: The COMPASS_SCALE written: magfit's corrected field is already in physical milligauss.
SCALE = 1.0
NAMES = (
    "COMPASS_OFS_X",
    "COMPASS_OFS_Y",
    "COMPASS_OFS_Z",
    "COMPASS_DIA_X",
    "COMPASS_DIA_Y",
    "COMPASS_DIA_Z",
    "COMPASS_ODI_X",
    "COMPASS_ODI_Y",
    "COMPASS_ODI_Z",
    "COMPASS_SCALE",
)


def ardupilot_parameters(calibration: Calibration, unit: str | None = None) -> dict[str, float]:
    """The ten COMPASS_* values (milligauss offsets), after checking ArduPilot's limits.

    Parameters
    ----------
    calibration : Calibration
        The calibration; ``offset`` and ``field_strength`` in the samples' unit.
    unit : str or None
        The samples' unit, overriding ``calibration.unit``; must be physical (not counts).

    Returns
    -------
    dict
        Parameter name -> value, in the order of :data:`NAMES`.

    Raises
    ------
    ExportError
        No physical unit, or ArduPilot would reject the values (see the module docstring).
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    source = physical_unit(calibration, unit, "ardupilot", "milligauss")
    k = factor(source, "mG")
    # The field first: a wrong unit shows there, before it inflates the offset.
    field = k * calibration.field_strength
    if not FIELD_RANGE_MG[0] <= field <= FIELD_RANGE_MG[1]:
        raise ExportError(
            f"ArduPilot would refuse to arm ('Check mag field'): the corrected field is {field:.4g} mG, outside "
            f"{FIELD_RANGE_MG[0]:.0f}-{FIELD_RANGE_MG[1]:.0f} mG; check the unit of the samples "
            f"(unit={source.name!r} was used)"
        )
    offsets = -k * calibration.offset  # ArduPilot adds its offsets: mag += OFS
    length = float(np.linalg.norm(offsets))
    if length > OFFSET_MAX_MG:
        raise ExportError(
            f"ArduPilot would refuse to arm: the compass offset is {length:.0f} mG long, above COMPASS_OFFS_MAX "
            f"({OFFSET_MAX_MG:.0f} mG by default); mount the compass further from magnetised parts and recalibrate"
        )
    matrix = symmetric_matrix(calibration, "ardupilot").matrix
    diagonal = np.diag(matrix)
    offdiagonal = np.array([matrix[0, 1], matrix[0, 2], matrix[1, 2]])
    low, high = DIAGONAL_RANGE
    if not np.all((diagonal > low) & (diagonal < high)):
        raise ExportError(
            f"ArduPilot's calibrator accepts COMPASS_DIA only in ({low}, {high}), got "
            f"{np.array2string(diagonal, precision=4)}; the soft-iron distortion is too strong for ArduPilot"
        )
    if not np.all(np.abs(offdiagonal) < OFFDIAGONAL_MAX):
        raise ExportError(
            f"ArduPilot's calibrator accepts |COMPASS_ODI| < {OFFDIAGONAL_MAX} only, got "
            f"{np.array2string(offdiagonal, precision=4)}; the soft-iron distortion is too strong for ArduPilot"
        )
    values = [*offsets, *diagonal, *offdiagonal, SCALE]
    return dict(zip(NAMES, (float(v) for v in values), strict=True))


def write_ardupilot(calibration: Calibration, unit: str | None = None) -> str:
    """The calibration as an ArduPilot ``.param`` file (``NAME,VALUE`` lines; see the module docstring)."""
    parameters = ardupilot_parameters(calibration, unit)
    source = physical_unit(calibration, unit, "ardupilot", "milligauss")
    k = factor(source, "mG")
    note = symmetric_matrix(calibration, "ardupilot").note
    lines = [
        "# ArduPilot compass calibration (first compass: COMPASS_* parameters)",
        *(f"# {line}" for line in describe(calibration, source.name)),
        "# ArduPilot corrects each sample (AP_Compass_Backend::correct_field), in milligauss, body frame:",
        "#   mag += (OFS_X, OFS_Y, OFS_Z)",
        f"#   mag *= SCALE   (only if {SCALE_RANGE[0]} <= SCALE <= {SCALE_RANGE[1]}: Compass::have_scale_factor)",
        "#   mag = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]] * mag",
        f"# mapping: OFS = -offset * {float32_text(k)} ({source.name} -> mG), DIA/ODI = magfit's matrix, SCALE = 1;",
        f"#   ArduPilot's corrected field = {float32_text(k)} x magfit's, radius "
        f"{float32_text(k * calibration.field_strength)} mG",
        "# Samples must be ArduPilot's body-frame field logged with no calibration applied",
        "#   (COMPASS_OFS = 0, COMPASS_DIA = 1, COMPASS_ODI = 0, COMPASS_SCALE = 0).",
        "# Load: Mission Planner > Config > Full Parameter List > Load from file, or MAVProxy 'param load <file>'.",
    ]
    if note is not None:
        lines.append(f"# NOTE: {plain(note)}")
    beyond = [name for name in NAMES[:3] if abs(parameters[name]) > OFFSET_RANGE_MG]
    if beyond:
        lines += [
            f"# WARNING: {', '.join(beyond)} beyond +-{OFFSET_RANGE_MG:.0f} mG, the documented range: Mission Planner",
            "#   asks '<name> value is out of range. Do you want to continue?' when loading this file; answer Yes,",
            "#   or it keeps the old value (ArduPilot itself accepts offsets up to COMPASS_OFFS_MAX).",
        ]
    lines += [f"{name},{float32_text(value)}" for name, value in parameters.items()]
    return "\n".join(lines) + "\n"
