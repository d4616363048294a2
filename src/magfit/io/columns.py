"""Finding the magnetometer's x, y, z columns among the names of a file's columns (or an NPZ file's keys).

The rule, in words (docs/file-formats.md says the same for users):

1. Every name is normalised: units in brackets are dropped (``MagX(uT)`` -> ``MagX``), camelCase is split
   (``magX`` -> ``mag_X``, ``imuMx`` -> ``imu_Mx``) and the result is lower-cased.
2. An *axis letter* is an ``x``, ``y`` or ``z`` that ends the name or a word of it (``mx``, ``mag_x``,
   ``mx_raw``, ``mag.x``) or starts it (``x_mag``). What stands before and after it (``imu_m`` + ``x`` +
   ``""``) is the name's *stem*; three names with the same stem and the three axis letters form a triple.
3. The words of the stem decide what the triple is. Words of another sensor or quantity (``a``, ``acc``,
   ``g``, ``gyro``, ``w``, ``omega``, ``euler``, ``vel``, ``pos`` ...) reject it: an accelerometer or a gyro
   is never taken for a magnetometer. A magnetometer word (``mag*``, ``compass``, ``field``, or a single
   ``m`` / ``b`` glued before the axis: ``mx``, ``imu_mx``, ``Bx``, ``m_x``) scores 2; a stem made only of
   neutral words (``""`` as in bare ``x``, ``imu``, ``sensor``, ``axis``, units, digits) scores 1; any other
   word rejects the triple (magfit does not guess at names it does not know).
4. ``raw`` / ``uncal`` add 0.5, ``cal`` / ``scaled`` / ``filtered`` / ``corrected`` ... subtract 0.5: the raw
   readings are the ones to calibrate.
5. The single best-scoring triple wins. Several at the best score (two magnetometers: ``imu_mx..`` and
   ``mag_x..``) is an ambiguity that the caller reports, listing them, instead of picking one.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["ColumnTriple", "find_magnetometer_columns", "name_words"]

_AXES = ("x", "y", "z")
#: Words that mark a magnetometer anywhere in the stem (plus any word starting with "mag").
_MAG_WORDS = frozenset({"compass", "field", "mfield", "bfield", "magnetic", "magnetometer", "mag", "magn"})
#: Single letters that mean a magnetometer only when glued before the axis letter (mx, imu_mx, Bx, m_x).
_MAG_LETTERS = frozenset({"m", "b"})
#: Words of other sensors and quantities: a triple containing one is never a magnetometer.
_OTHER_WORDS = frozenset(
    {
        "a", "acc", "accel", "acceleration", "accelerometer", "lin", "linear", "grav", "gravity",
        "g", "gyr", "gyro", "gyroscope", "w", "omega", "rate", "rates", "ang", "angle", "angular", "rot",
        "rotation", "euler", "q", "quat", "quaternion", "att", "attitude", "orientation", "orient",
        "vel", "velocity", "v", "pos", "position", "p", "d", "dist", "displacement", "e", "r", "o",
        "gps", "speed", "force", "torque", "offset", "bias", "std", "var", "sigma", "err", "error",
    }
)  # fmt: skip
#: Words that say nothing about the sensor: they neither help nor hurt.
_NEUTRAL_WORDS = frozenset(
    {
        "imu", "sensor", "sens", "data", "value", "val", "axis", "reading", "meas", "measured",
        "measurement", "sample", "body", "ut", "nt", "mt", "gauss", "mgauss", "counts", "count", "lsb", "adc",
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


def normalise_name(name: str) -> str:
    """Drop bracketed units, split camelCase and lower-case a column name (rule 1)."""
    text = _UNITS_IN_BRACKETS.sub("", name.strip().lstrip("\ufeff"))
    return _CAMEL_BOUNDARY.sub("_", text.strip()).lower()


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
        elif word in _OTHER_WORDS or word.startswith(("acc", "gyr")):
            return None
        elif word in _MAG_WORDS or word.startswith("mag"):
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
