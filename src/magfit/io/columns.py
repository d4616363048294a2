"""Finding the magnetometer's x, y, z columns: by the names of a file's columns (or an NPZ file's keys), or,
in a file without a header, by what the columns hold (:func:`choose_columns_by_content`).

The rule, in words (docs/file-formats.md says the same for users):

1. Every name is normalised: an array index 0, 1 or 2 is the axis x, y or z (``magADC[0]`` -> ``magADC_x``,
   as blackbox_decode and ulog2csv write vectors), units in brackets are dropped (``MagX(uT)`` -> ``MagX``)
   and so is a unit written as a word after the first (``mag_x_uT`` -> ``mag_x``, ``magnetometer_ga[0]``
   -> ``magnetometer_x``; :func:`name_unit` keeps it), camelCase is split (``magX`` -> ``mag_X``,
   ``imuMx`` -> ``imu_Mx``) and the result is lower-cased.
2. An *axis letter* is an ``x``, ``y`` or ``z`` that ends the name or a word of it (``mx``, ``mag_x``,
   ``mx_raw``, ``mag.x``) or starts it (``x_mag``). What stands before and after it (``imu_m`` + ``x`` +
   ``""``) is the name's *stem*; three names with the same stem and the three axis letters form a triple.
3. The words of the stem decide what the triple is. Words of another sensor or quantity (``a``, ``acc``,
   ``g``, ``gyro``, ``w``, ``omega``, ``euler``, ``vel``, ``pos`` ...) reject it: an accelerometer or a gyro
   is never taken for a magnetometer. A magnetometer word (``mag*``, ``flux*``, ``compass``, ``field``, or a
   single ``m`` / ``b`` / ``h`` glued before the axis: ``mx``, ``imu_mx``, ``Bx``, ``hx``, ``m_x``) scores 2;
   a single letter after a magnetometer word labels one of several sensors (``flux_a_x``), no quantity; a stem
   made only of neutral words (``""`` as in bare ``x``, ``imu``, ``sensor``, ``axis``, units, digits) scores 1;
   any other word rejects the triple (magfit does not guess at names it does not know).
4. ``raw`` / ``uncal`` add 0.5, ``cal`` / ``scaled`` / ``filtered`` / ``corrected`` ... subtract 0.5: the raw
   readings are the ones to calibrate.
5. The single best-scoring triple wins. Several at the best score (two magnetometers: ``imu_mx..`` and
   ``mag_x..``) is an ambiguity that the caller reports, listing them, instead of picking one.

The columns of the usual converters are recognised by their names and the header around them
(:func:`recognise_converter`): their unit, and what the firmware did to the field before logging it.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import OptionError
from ..units import get_unit

__all__ = [
    "ColumnTriple",
    "ContentChoice",
    "Converter",
    "choose_columns_by_content",
    "ellipsoid_spread",
    "find_magnetometer_columns",
    "name_unit",
    "name_words",
    "recognise_converter",
]

_AXES = ("x", "y", "z")
#: Words that mark a magnetometer anywhere in the stem (plus any word starting with "mag").
_MAG_WORDS = frozenset(
    {"compass", "field", "mfield", "bfield", "magnetic", "magnetometer", "mag", "magn", "flux", "fluxgate"}
)
#: Single letters that mean a magnetometer only when glued before the axis letter (mx, imu_mx, Bx, m_x; hx for
#: the H field, as WitMotion and u-blox exports name it).
_MAG_LETTERS = frozenset({"m", "b", "h"})
#: Words of other sensors and quantities: a triple containing one is never a magnetometer.
_OTHER_WORDS = frozenset(
    {
        "a", "acc", "accel", "acceleration", "accelerometer", "lin", "linear", "grav", "gravity",
        "g", "gyr", "gyro", "gyroscope", "w", "omega", "rate", "rates", "ang", "angle", "angular", "rot",
        "rotation", "euler", "q", "quat", "quaternion", "att", "attitude", "orientation", "orient",
        "vel", "velocity", "v", "pos", "position", "p", "d", "dist", "displacement", "e", "r", "o",
        "gps", "speed", "force", "torque", "offset", "bias", "std", "var", "sigma", "err", "error",
        "ref", "reference", "model", "wmm", "igrf", "expected", "predicted",
    }
)  # fmt: skip
#: Words that say nothing about the sensor: they neither help nor hurt.
_NEUTRAL_WORDS = frozenset(
    {
        "imu", "sensor", "sens", "data", "value", "val", "axis", "reading", "meas", "measured",
        "measurement", "sample", "body", "ut", "nt", "mt", "gauss", "mgauss", "ga", "counts", "count", "lsb", "adc",
    }
)  # fmt: skip
_RAW_WORDS = frozenset({"raw", "uncal", "uncalibrated", "uncomp", "uncompensated"})
_PROCESSED_WORDS = frozenset(
    {
        "cal", "calib", "calibrated", "scaled", "scale", "corrected", "corr", "comp", "compensated",
        "filtered", "filt", "norm", "normalized", "normalised", "unit", "fused", "est", "estimate",
        "earth", "world", "ned", "enu", "smooth", "smoothed",
    }
)  # fmt: skip

_UNITS_IN_BRACKETS = re.compile(r"[\(\[\{<][^\)\]\}>]*[\)\]\}>]")
#: An array index 0, 1, 2 in brackets: blackbox_decode's ``magADC[0]``, ulog2csv's ``magnetometer_ga[0]``.
_INDEX_AXIS = re.compile(r"\[\s*([012])\s*\]")
#: Splits a name into its words and what separates them (kept, so that the name can be put back together).
_TOKENS = re.compile(r"([^0-9A-Za-z\u00b5\u03bc]+)")
_CAMEL_BOUNDARY = re.compile(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])")
_WORD_SPLIT = re.compile(r"[^a-z0-9]+")


@dataclass(frozen=True)
class ColumnTriple:
    """One candidate set of magnetometer columns.

    Attributes
    ----------
    indices : tuple of 3 int
        0-based positions of the x, y and z columns among the names given.
    names : tuple of 3 str
        Their names, in x, y, z order.
    score : float
        How magnetometer-like the names are (module docstring, rules 3-4); higher is better.
    """

    indices: tuple[int, int, int]
    names: tuple[str, str, str]
    score: float

    def describe(self) -> str:
        """The triple as the user would type it: ``mag_x,mag_y,mag_z``."""
        return ",".join(self.names)


def _unit_word(word: str) -> str | None:
    """The physical unit a word of a name is (``uT``, ``nT``, ``mG``, ``ga``, ``gauss``, ``T``, ``G``), or None.

    Single letters count only in capitals (``mag_x_T``): a lower-case ``t`` or ``g`` is more likely a time
    or gravity. Raw counts are not a unit a name states (``mx_raw`` is a raw magnetometer, not a unit)."""
    if len(word) == 1:
        return word if word in ("T", "G") else None
    try:
        unit = get_unit(word)
    except OptionError:
        return None
    return unit.name if unit.is_physical else None


def name_unit(name: str) -> str | None:
    """The unit a column name states, as :mod:`magfit.units` names it, or None.

    In brackets (``MagX(uT)``, ``mag_x [mG]``) or as a word of its own after the first (``mag_x_uT``,
    ``magnetometer_ga[0]``, ``Bx_nT``).
    """
    text = name.strip().lstrip("\ufeff")
    for bracketed in _UNITS_IN_BRACKETS.findall(text):
        unit = _unit_word(bracketed[1:-1].strip())
        if unit is not None:
            return unit
    words = [word for word in _TOKENS.split(_UNITS_IN_BRACKETS.sub(" ", text))[::2] if word]
    for word in words[1:]:
        unit = _unit_word(word)
        if unit is not None:
            return unit
    return None


def normalise_name(name: str) -> str:
    """An index for the axis, bracketed units and unit words dropped, camelCase split, lower-cased (rule 1)."""
    text = _INDEX_AXIS.sub(lambda match: "_" + _AXES[int(match.group(1))], name.strip().lstrip("\ufeff"))
    text = _UNITS_IN_BRACKETS.sub("", text).strip()
    # A unit word is dropped before camelCase is split (uT would become u_t); never the first word (G_x is a gyro).
    parts = _TOKENS.split(text)
    words = [i for i in range(0, len(parts), 2) if parts[i]]
    for i in words[1:]:
        if _unit_word(parts[i]) is not None:
            parts[i] = ""
    return _CAMEL_BOUNDARY.sub("_", "".join(parts)).lower()


def name_words(text: str) -> list[str]:
    """The words of a normalised name fragment, trailing digits removed (``mag1`` -> ``mag``)."""
    return [word.rstrip("0123456789") or word for word in _WORD_SPLIT.split(text) if word]


def _axis_splits(normalised: str) -> list[tuple[str, str, str]]:
    """Every way of reading the name as ``stem-before + axis + stem-after`` (rule 2)."""
    splits = []
    for i, char in enumerate(normalised):
        if char not in _AXES:
            continue
        ends_word = i + 1 == len(normalised) or not normalised[i + 1].isalnum()
        starts_word = i == 0 or not normalised[i - 1].isalnum()
        if ends_word or starts_word:
            splits.append((normalised[:i], char, normalised[i + 1 :]))
    return splits


def _magnetic_word(word: str) -> bool:
    """A word that marks a magnetometer: one of :data:`_MAG_WORDS`, or starting with "mag" or "flux" (a
    fluxgate: ``FLUXA_X``)."""
    return word in _MAG_WORDS or word.startswith(("mag", "flux"))


def _stem_score(before: str, after: str) -> float | None:
    """Score of a stem (rules 3-4), or None when the triple is not a magnetometer."""
    before_words = name_words(before)
    words = before_words + name_words(after)
    magnetic = False
    score = 0.0
    for position, word in enumerate(words):
        # A single "m" / "b" counts only as the last word before the axis (mx, imu_mx, m_x, Bx):
        # after it ("x_m") it is more likely a unit such as metres, and rejected as unknown below.
        if word in _MAG_LETTERS and position == len(before_words) - 1:
            magnetic = True
        elif len(word) == 1 and position > 0 and _magnetic_word(words[position - 1]):
            pass  # a sensor's label after a magnetometer word: MagNav's flux_a_x ... flux_d_x
        elif word in _OTHER_WORDS or word.startswith(("acc", "gyr")):
            return None
        elif _magnetic_word(word):
            magnetic = True
        elif word in _RAW_WORDS:
            score += 0.5
        elif word in _PROCESSED_WORDS:
            score -= 0.5
        elif word not in _NEUTRAL_WORDS and not word.isdigit():
            return None
    return score + (2.0 if magnetic else 1.0)


def find_magnetometer_columns(names: Sequence[str]) -> list[ColumnTriple]:
    """All candidate magnetometer triples among ``names``, best first.

    Parameters
    ----------
    names : sequence of str
        Column names (or NPZ keys), in file order.

    Returns
    -------
    list of ColumnTriple
        Candidates sorted by decreasing score, then by position in the file. The caller takes the first
        one when it is the only one with the best score, and reports an ambiguity otherwise.
    """
    groups: dict[tuple[str, str], dict[str, list[int]]] = {}
    for index, name in enumerate(names):
        for before, axis, after in _axis_splits(normalise_name(name)):
            groups.setdefault((before, after), {}).setdefault(axis, []).append(index)
    triples: dict[tuple[int, int, int], ColumnTriple] = {}
    for (before, after), axes in groups.items():
        if set(axes) != set(_AXES):
            continue
        score = _stem_score(before, after)
        if score is None:
            continue
        # Duplicate names give several combinations: all are listed, so the caller reports an ambiguity.
        for combo in itertools.product(axes["x"], axes["y"], axes["z"]):
            if len(set(combo)) == 3 and combo not in triples:
                triples[combo] = ColumnTriple(combo, (names[combo[0]], names[combo[1]], names[combo[2]]), score)
    return sorted(triples.values(), key=lambda triple: (-triple.score, triple.indices))


# ---------------------------------------------------------------------------------------------- converters


@dataclass(frozen=True)
class Converter:
    """The tool that wrote a file's magnetometer columns, recognised by their names (:func:`recognise_converter`).

    Attributes
    ----------
    name : str
        The tool and the message or field, in words (``PX4 ulog2csv sensor_mag``).
    unit : str or None
        The unit the tool writes the field in, as :mod:`magfit.units` names it (``counts`` for raw ADC values).
    note : str or None
        What the firmware did to the field before it was logged, when a user must know it (a calibration
        already applied: the fit is then a correction on top of it).
    """

    name: str
    unit: str | None
    note: str | None = None

    def describe(self) -> str:
        """``ArduPilot MAG (mavlogdump), mG; logged after ...`` for a message."""
        text = self.name + (f", {self.unit}" if self.unit else "")
        return text + (f"; {self.note}" if self.note else "")


_BLACKBOX = Converter(
    "Betaflight/INAV blackbox_decode magADC",
    "counts",
    # src/main/sensors/compass.c, compassUpdate: magADC = the chip's counts, board-aligned, minus magZero.
    "raw counts after the board alignment, minus the offset the firmware stores (mag_calibration / magzero_*): "
    "a fitted offset adds to that one",
)
_PX4_VEHICLE = Converter(
    "PX4 ulog2csv magnetometer_ga (vehicle_magnetometer, or an old sensor_combined)",
    "G",
    # src/modules/sensors/vehicle_magnetometer/VehicleMagnetometer.cpp: published after the CAL_MAGn_* correction.
    "PX4's calibrated field (CAL_MAGn_* applied, rotated into the vehicle frame): a fit on it is a correction "
    "on top of that calibration; for a new one fit the .ulg itself (magfit undoes it) or its raw sensor_mag",
)
_PX4_SENSOR_MAG = Converter("PX4 ulog2csv sensor_mag (raw)", "G")
_ARDUPILOT_MAG = Converter(
    "ArduPilot DataFlash MAG (mavlogdump --format csv)",
    "mG",
    # libraries/AP_Compass/AP_Compass_Backend.cpp, correct_field: offsets, DIA/ODI, scale and motor compensation.
    "logged after ArduPilot's current calibration (COMPASS_OFS*, DIA/ODI, SCALE, motor compensation): a fit on "
    "it is a correction on top of it; for a new one fit the .bin log itself (magfit undoes it with its PARM)",
)
# sensor_msgs/MagneticField: "magnetic_field: x, y, and z components of the field vector in Tesla".
_ROS = Converter("ROS sensor_msgs/MagneticField (CSV export)", "T")

_BLACKBOX_NAME = re.compile(r"magADC\[\s*[012]\s*\]")
_PX4_VEHICLE_NAME = re.compile(r"magnetometer_ga\[\s*[012]\s*\]")
_ARDUPILOT_NAME = re.compile(r"(?P<prefix>MAG\d?\.)?Mag[XYZ]")


def recognise_converter(names: Sequence[str], header: Sequence[str]) -> Converter | None:
    """The converter that wrote the magnetometer columns ``names`` of a file with the columns ``header``, or None.

    Blackbox_decode's ``magADC[0..2]`` (Betaflight, INAV); PX4's ulog2csv (``vehicle_magnetometer``'s
    ``magnetometer_ga[0..2]``, ``sensor_mag``'s ``x, y, z`` beside ``device_id`` and ``error_count``);
    mavlogdump's ArduPilot ``MagX..Z`` (beside ``TimeUS``); a ROS ``sensor_msgs/MagneticField`` exported to
    CSV (``field.magnetic_field.x``, ``.magnetic_field.x``).
    """
    stripped = [name.strip().lstrip("\ufeff") for name in names]
    others = {name.strip().lstrip("\ufeff") for name in header}
    if all(_BLACKBOX_NAME.fullmatch(name) for name in stripped):
        return _BLACKBOX
    if all(_PX4_VEHICLE_NAME.fullmatch(name) for name in stripped):
        return _PX4_VEHICLE
    if stripped == ["x", "y", "z"] and "device_id" in others and others & {"error_count", "is_external"}:
        return _PX4_SENSOR_MAG
    matches = [_ARDUPILOT_NAME.fullmatch(name) for name in stripped]
    if all(matches) and any(f"{match.group('prefix') or ''}TimeUS" in others for match in matches if match):
        return _ARDUPILOT_MAG
    if all({"magnetic", "field"} <= set(name_words(normalise_name(name))) for name in stripped):
        return _ROS
    return None


# ---------------------------------------------------------------------------------------------- by content

#: Rows the content rule looks at (the first ones, and rows from further in for a file longer than its
#: head): enough for a stable fit, cheap to parse.
CONTENT_ROWS = 2000
#: A column is taken for a time or a counter when it never decreases (or never increases) over at least
#: this many rows of the head and changes in at least half of its steps.
MONOTONIC_MIN_ROWS = 10
#: Two disjoint triples both within this factor of the best spread are an ambiguity (an accelerometer
#: held still has a nearly constant norm too): the caller asks for the columns instead of guessing.
AMBIGUITY_FACTOR = 2.0


#: A triple whose field direction stays within this angle (degrees) of its mean over the head does not turn
#: with a sensor on a moving body: a field in the world frame (a model or reference field, N/E/D).
STILL_DIRECTION_DEG = 2.0
#: A triple whose raw norm varies by less than this fraction of its mean is a model or reference field in
#: the body frame: no magnetometer's noise, quantisation and uncorrected hard iron together are that small.
MODEL_NORM_SPREAD = 1e-5


@dataclass(frozen=True)
class ContentChoice:
    """The x, y, z columns of a file without a header, chosen by what they hold.

    Attributes
    ----------
    indices : tuple of 3 int
        0-based positions of the columns chosen, in file order.
    monotonic : tuple of int
        Columns passed over because they only grow (or only shrink) over the head: a time or a counter.
    constant : tuple of int
        Columns passed over because they hold one value.
    spread : float or None
        Relative spread (std / mean) of the chosen columns' norm after an ellipsoid fit to the head, when
        several triples were compared; None when no choice had to be made.
    rivals : tuple of tuple of 3 int
        Other triples whose spread is within :data:`AMBIGUITY_FACTOR` of the best: a non-empty tuple means
        the content cannot decide (the caller reports it).
    angles : tuple of int
        Columns passed over as angles: one that behaves like a heading (it wraps, or covers more than half a
        turn, in degrees or radians) and the two written beside it within a tilt's range (roll, pitch, yaw).
    passed : tuple of (tuple of 3 int, str)
        Triples of neighbouring columns passed over, each with why in words (a model or reference field;
        angles; time).
    candidates : tuple of (tuple of 3 int, float)
        The triples compared by content (neighbouring columns, none passed over), each with its spread.
    """

    indices: tuple[int, int, int]
    monotonic: tuple[int, ...] = ()
    constant: tuple[int, ...] = ()
    spread: float | None = None
    rivals: tuple[tuple[int, int, int], ...] = ()
    angles: tuple[int, ...] = ()
    passed: tuple[tuple[tuple[int, int, int], str], ...] = ()
    candidates: tuple[tuple[tuple[int, int, int], float], ...] = ()

    def describe(self, labels: Sequence[str]) -> str | None:
        """Why these columns, in words (``column 1 is monotonic: time or a counter``); None when obvious."""
        reasons = []
        if self.monotonic:
            names = ", ".join(labels[i] for i in self.monotonic)
            verb = "is" if len(self.monotonic) == 1 else "are"
            reasons.append(f"{names} {verb} monotonic: time or a counter")
        if self.constant:
            reasons.append(f"{', '.join(labels[i] for i in self.constant)} constant")
        if self.angles:
            reasons.append(f"{', '.join(labels[i] for i in self.angles)} angles")
        for triple, why in self.passed:  # the model or reference fields (mixed triples: magfit inspect says them)
            if not set(triple) & {*self.monotonic, *self.constant, *self.angles} and not why.startswith("sizes"):
                reasons.append(f"{', '.join(labels[i] for i in triple)} {why}")
        if self.spread is not None:
            reasons.append(f"the most constant norm under an ellipsoid fit ({100 * self.spread:.2g} % spread)")
        return "; ".join(reasons) or None

    def what(self, labels: Sequence[str]) -> list[tuple[str, str]]:
        """Each group of columns the rule looked at and what it took it for, in file order (``magfit inspect``)."""
        said: list[tuple[int, str, str]] = []
        for column in self.monotonic:
            said.append((column, labels[column], "monotonic: time or a counter"))
        for column in self.constant:
            said.append((column, labels[column], "constant"))
        if self.angles:
            said.append((self.angles[0], ", ".join(labels[i] for i in self.angles), "angles (attitude), not a field"))
        for triple, why in self.passed:
            if not set(triple) & {*self.monotonic, *self.constant, *self.angles}:
                said.append((triple[0], ", ".join(labels[i] for i in triple), why))
        for triple, spread in self.candidates:
            if self.rivals and (triple == self.indices or triple in self.rivals):
                role = "a candidate magnetometer, as likely as another: not chosen (give the columns)"
            else:
                role = "the magnetometer" if triple == self.indices else "less constant a norm than the magnetometer"
            said.append((triple[0], ", ".join(labels[i] for i in triple), f"{role} ({100 * spread:.2g} % spread)"))
        if not self.candidates:
            said.append((self.indices[0], ", ".join(labels[i] for i in self.indices), "the magnetometer"))
        return [(names, text) for _, names, text in sorted(said, key=lambda item: item[0])]


def _is_monotonic(column: NDArray[np.float64]) -> bool:
    values = column[np.isfinite(column)]
    if values.size < MONOTONIC_MIN_ROWS:
        return False
    steps = np.diff(values)
    moving = np.count_nonzero(steps)
    return bool(moving >= 0.5 * steps.size and (np.all(steps >= 0) or np.all(steps <= 0)))


def ellipsoid_spread(points: NDArray[np.float64]) -> float | None:
    """Relative spread (std / mean) of the "radius" of ``points`` (N, 3) about their algebraic ellipsoid fit.

    The quadric ``a x² + b y² + c z² + 2d xy + 2e xz + 2f yz + 2g x + 2h y + 2i z = 1`` is fitted by least
    squares in a centred, scaled frame; None when it is not an ellipsoid (not positive definite) or the
    points are too few. Small for the three axes of a magnetometer turned about (a near-constant norm
    once the hard and soft iron are undone), large for columns that hold different quantities.
    """
    finite = points[np.isfinite(points).all(axis=1)]
    if finite.shape[0] < 20:
        return None
    scale = finite.std(axis=0)
    if not np.all(scale > 0):
        return None
    z = (finite - finite.mean(axis=0)) / scale
    x, y, w = z[:, 0], z[:, 1], z[:, 2]
    design = np.column_stack([x * x, y * y, w * w, 2 * x * y, 2 * x * w, 2 * y * w, 2 * x, 2 * y, 2 * w])
    # Normal equations (9 x 9): a thousand times cheaper than an SVD of the design, and well conditioned in
    # this centred, scaled frame; the SVD only when they are singular.
    try:
        p = np.linalg.solve(design.T @ design, design.sum(axis=0))
    except np.linalg.LinAlgError:
        p = np.linalg.lstsq(design, np.ones(len(z)), rcond=None)[0]
    quadratic = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    try:
        centre = -np.linalg.solve(quadratic, p[6:9])
    except np.linalg.LinAlgError:
        return None
    level = 1.0 + centre @ quadratic @ centre
    if level <= 0 or np.linalg.eigvalsh(quadratic).min() <= 0:
        return None
    shifted = z - centre
    radius = np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", shifted, quadratic / level, shifted), 0.0))
    mean = float(radius.mean())
    return float(radius.std() / mean) if mean > 0 else None


def _turn(column: NDArray[np.float64]) -> float | None:
    """The turn (360 or 2π) a column's values lie within as angles (±half a turn or 0 to a turn), or None."""
    values = column[np.isfinite(column)]
    if values.size < MONOTONIC_MIN_ROWS:
        return None
    low, high = float(values.min()), float(values.max())
    for turn in (2 * np.pi, 360.0):
        if (low >= -turn / 2 - 1e-9 and high <= turn / 2 + 1e-9) or (low >= -1e-9 and high <= turn + 1e-9):
            return turn
    return None


def _angle_seed(column: NDArray[np.float64]) -> tuple[float, bool] | None:
    """The turn of a column that behaves like a heading and whether it wraps, or None: within one turn,
    smooth (small steps between neighbouring rows), and either a jump of nearly a turn (it wraps) or more
    than an eighth of a turn covered (then only with tilts beside it: :func:`_angle_group`)."""
    turn = _turn(column)
    if turn is None:
        return None
    values = column[np.isfinite(column)]
    steps = np.abs(np.diff(values))
    wraps = bool(np.any(steps > 0.75 * turn))
    if float(np.quantile(steps[steps <= 0.75 * turn], 0.9)) >= 0.02 * turn:
        return None
    return (turn, wraps) if wraps or float(values.max() - values.min()) > turn / 8 else None


def _angle_group(
    values: NDArray[np.float64],
    numeric: Sequence[int],
    candidates: Sequence[int],
    seed: int,
    turn: float,
    wraps: bool,
    fieldlike: frozenset[int] = frozenset(),
) -> tuple[int, ...]:
    """The heading-like column with the two neighbours written beside it that are a vehicle's tilts (roll
    and pitch: within a quarter turn, averaging within a tenth of it, smooth; and, unless the heading wraps,
    no near-constant norm as a field's axes keep: :data:`FIELD_MAX_SPREAD`): of the windows of three neighbouring
    columns holding it, the one whose tilts stay closest to zero. None such: the seed alone when it wraps
    (an angle all the same), else nothing (a field's axis that happens to stay within a turn). Unless the
    heading wraps, no window takes a column of ``fieldlike`` (three neighbouring columns that keep a
    near-constant norm: a sensor's axes, whose µT values stay within a turn as angles do)."""
    if not wraps and seed in fieldlike:
        return ()
    order = list(numeric)
    position = order.index(seed)
    best: tuple[float, tuple[int, ...]] | None = None
    for first in range(max(position - 2, 0), position + 1):
        window = order[first : first + 3]
        if len(window) != 3 or not set(window) <= set(candidates) or (not wraps and set(window) & fieldlike):
            continue
        tilts = [values[:, j][np.isfinite(values[:, j])] for j in window if j != seed]
        largest = max(float(np.abs(tilt).max()) if tilt.size else np.inf for tilt in tilts)
        centred = all(
            tilt.size > 1
            and abs(float(tilt.mean())) <= turn / 10
            and float(np.quantile(np.abs(np.diff(tilt)), 0.9)) < 0.02 * turn  # smooth, as an estimator's
            for tilt in tilts
        )
        if not (largest <= turn / 4 + 1e-9 and centred and (best is None or largest < best[0])):
            continue
        # Without a wrap, a field's three axes in µT can look the same: they keep a near-constant norm.
        spread = ellipsoid_spread(values[:, window])
        if wraps or spread is None or spread > FIELD_MAX_SPREAD:
            best = (largest, tuple(window))
    if best is not None:
        return best[1]
    return (seed,) if wraps else ()


#: An attitude's three angles outline no ellipsoid with a norm this constant (std / mean after the fit); a
#: field's axes (µT values within ±180 too) do.
FIELD_MAX_SPREAD = 0.1

#: Three columns whose sizes (root mean square) differ by more than this factor hold different quantities
#: (an angle in degrees beside a field in nT): a field's three axes are of one size over a recording.
SIZE_RATIO = 100.0


def _world_field(points: NDArray[np.float64]) -> str | None:
    """Why a triple is a model or reference field and no magnetometer, or None (module constants)."""
    finite = points[np.isfinite(points).all(axis=1)]
    norms = np.linalg.norm(finite, axis=1)
    if finite.shape[0] < MONOTONIC_MIN_ROWS or not np.all(norms > 0):
        return None
    sizes = np.sqrt(np.mean(finite**2, axis=0))
    if float(sizes.max()) > SIZE_RATIO * float(sizes.min()):
        return f"sizes {float(sizes.max()) / float(sizes.min()):.2g}x apart: different quantities, not one field's axes"
    mean = float(norms.mean())
    if float(norms.std()) < MODEL_NORM_SPREAD * mean:
        constant = float(norms.std()) / mean
        return f"a norm constant to {constant:.1g} of itself, below any sensor's noise: a model or reference field"
    unit = finite / norms[:, None]
    centre = unit.mean(axis=0)
    centre /= np.linalg.norm(centre)
    turned = float(np.degrees(np.arccos(np.clip(unit @ centre, -1.0, 1.0))).max())
    if turned < STILL_DIRECTION_DEG:
        return f"turns by {turned:.2g}° at most: a field fixed in the world (a model or reference field, N/E/D)"
    return None


#: Gravity in m/s² and in g: a triple whose norm stays this close (:data:`GRAVITY_TOLERANCE`) is likelier an
#: accelerometer's than a magnetometer's (no Earth field is 9.8 µT, 9.8 G or about 1 G).
GRAVITY_NORMS = (9.80665, 1.0)
GRAVITY_TOLERANCE = 0.05


def _gravity_like(points: NDArray[np.float64]) -> bool:
    """Whether the median norm of ``points`` is gravity's in m/s² or g (:data:`GRAVITY_NORMS`)."""
    finite = points[np.isfinite(points).all(axis=1)]
    if not len(finite):
        return False
    norm = float(np.median(np.linalg.norm(finite, axis=1)))
    return any(abs(norm - g) <= GRAVITY_TOLERANCE * g for g in GRAVITY_NORMS)


def choose_columns_by_content(head: NDArray[np.float64], numeric: Sequence[int]) -> ContentChoice:
    """Choose the magnetometer's three columns of a file without a header from the values of its first rows.

    Rules, in order (docs/file-formats.md says the same for users):

    1. Only ``numeric`` columns count. A column that only grows or only shrinks over the head (at least
       :data:`MONOTONIC_MIN_ROWS` rows, changing in half of its steps) is a time or a counter; a column
       with one value holds no axis. Both are passed over.
    2. Three columns left are x, y, z in file order.
    3. More than three: a column that behaves like a heading (:func:`_angle_seed`: smooth, within one turn
       of degrees or radians, and it wraps or covers an eighth of a turn) and the two written beside it that
       behave like a vehicle's tilts (:func:`_angle_group`) are an attitude, passed over. The candidates
       are three *neighbouring* numeric columns (a writer puts x, y, z side by side) with none passed over
       and none reaching into another group (three columns drawn from different groups are never a
       magnetometer). A triple that does not turn (its direction within
       :data:`STILL_DIRECTION_DEG`) or whose norm is constant far below any sensor's noise
       (:data:`MODEL_NORM_SPREAD`) is a model or reference field, and one whose columns' sizes differ by
       more than :data:`SIZE_RATIO` holds different quantities: both passed over. Each candidate left is fitted
       with an ellipsoid (:func:`ellipsoid_spread`) and the one whose norm is most constant wins. Another
       triple, disjoint from it, within :data:`AMBIGUITY_FACTOR` of its spread, is a rival (``rivals``): the
       caller refuses to guess. So is any other triple within :data:`FIELD_MAX_SPREAD` when the best one's
       norm is gravity's (:func:`_gravity_like`): an accelerometer turned about keeps its norm as a
       magnetometer does, and may keep it better.
    4. Fewer than three left, or no triple outlining an ellipsoid: the first three of the varying columns,
       then the constant ones, then time and counters, as a last resort (in file order).

    Parameters
    ----------
    head : ndarray, shape (n_rows, n_columns)
        The first rows of the file as numbers (NaN where a cell is empty or not a number).
    numeric : sequence of int
        The columns that hold numbers (0-based).
    """
    values = np.asarray(head, dtype=np.float64)
    numeric = list(numeric)
    monotonic = [j for j in numeric if _is_monotonic(values[:, j])]
    constant = [j for j in numeric if j not in monotonic and np.unique(values[np.isfinite(values[:, j]), j]).size <= 1]
    left = [j for j in numeric if j not in monotonic and j not in constant]
    if len(left) == 3:
        return ContentChoice((left[0], left[1], left[2]), tuple(monotonic), tuple(constant))
    # The last resort prefers columns that vary, then constant ones (a flat recording), time and counters last.
    fallback = [*left, *constant, *monotonic]
    if len(left) > 3:
        # Three neighbouring columns that keep a near-constant norm are a sensor's axes (a magnetometer's, or an
        # accelerometer's turned about): none of them is taken for an attitude angle (:func:`_angle_group`).
        fieldlike = frozenset(
            j
            for k in range(len(numeric) - 2)
            if set(numeric[k : k + 3]) <= set(left)
            and (norm_spread := ellipsoid_spread(values[:, numeric[k : k + 3]])) is not None
            and norm_spread <= FIELD_MAX_SPREAD
            for j in numeric[k : k + 3]
        )
        angles: list[int] = []
        for j in left:
            if j not in angles and (seed := _angle_seed(values[:, j])) is not None:
                group = _angle_group(values, numeric, left, j, *seed, fieldlike=fieldlike)
                angles += [k for k in group if k not in angles and k in left]
        angles.sort()
        windows = [tuple(numeric[k : k + 3]) for k in range(len(numeric) - 2)]
        passed: list[tuple[tuple[int, int, int], str]] = []
        fields: set[int] = set()  # the columns of a model or reference field: a group of their own
        for window in windows:
            triple = (window[0], window[1], window[2])
            if set(triple) & {*monotonic, *constant, *angles}:
                continue
            why = _world_field(values[:, triple])
            if why is not None:
                passed.append((triple, why))
                if not why.startswith("sizes"):
                    fields.update(triple)
        scored: list[tuple[float, tuple[int, int, int]]] = []
        for window in windows:
            triple = (window[0], window[1], window[2])
            if set(triple) & {*monotonic, *constant, *angles, *fields} or any(t == triple for t, _ in passed):
                continue  # a triple reaching into another group is drawn from two sensors' columns
            spread = ellipsoid_spread(values[:, triple])
            if spread is not None:
                scored.append((spread, triple))
        if scored:
            best_spread, best = min(scored)
            rivals = tuple(
                triple
                for spread, triple in sorted(scored)
                if not set(triple) & set(best)
                and (
                    spread <= AMBIGUITY_FACTOR * best_spread
                    or (_gravity_like(values[:, best]) and spread <= FIELD_MAX_SPREAD)
                )
            )
            return ContentChoice(
                best, tuple(monotonic), tuple(constant), best_spread, rivals, tuple(angles), tuple(passed),
                tuple((triple, spread) for spread, triple in scored),
            )  # fmt: skip
        dropped = {*angles, *(j for triple, _ in passed for j in triple)}
        fallback = [j for j in fallback if j not in dropped] + [j for j in fallback if j in dropped]
        first = sorted((fallback + [j for j in range(values.shape[1]) if j not in fallback])[:3])
        return ContentChoice(
            (first[0], first[1], first[2]), tuple(j for j in monotonic if j not in first), (), None, (),
            tuple(j for j in angles if j not in first), tuple(passed),
        )  # fmt: skip
    first = sorted((fallback + [j for j in range(values.shape[1]) if j not in fallback])[:3])
    return ContentChoice((first[0], first[1], first[2]), tuple(j for j in monotonic if j not in first))
