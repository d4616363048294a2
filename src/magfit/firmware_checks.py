"""The firmwares' own acceptance tests of a compass calibration, replayed on the samples magfit has.

When ArduPilot's onboard calibration fails, the ground station says ``FAILED``, ``BAD_RADIUS`` or
``BAD_ORIENTATION`` and little more. The tests behind those words are simple and are replayed here on the log's
samples with magfit's fit, so that the user learns which test failed, by how much, and what to do.

**ArduPilot** (``libraries/AP_Compass/CompassCalibrator.cpp``). The calibrator's model is
``|S (x + ofs)| = r`` with ``S`` the symmetric matrix of ``diag`` and ``offdiag``; magfit's fit gives it as
``ofs = −offset``, ``r = field_strength`` and ``S`` the symmetric part of ``matrix`` (det 1, the diagonal near 1
as the calibrator's).

1. ``fit_acceptable()``: the fitness ``sqrt(mean((r − |S (x + ofs)|)²))`` (mG) at most ``COMPASS_CAL_FIT``
   (default 16); ``150 < r < 950`` mG (``FIELD_RADIUS_MIN/MAX``); every ``|ofs_i| < COMPASS_OFFS_MAX`` (default
   1800 mG; 600-1250 in older versions); every ``diag_i`` in (0.2, 5); every ``|offdiag_i| < 1``. A failure
   is ``FAILED``.
2. ``fix_radius()``, with a GNSS fix: ``correction = expected / r`` with ``expected`` the World Magnetic Model's
   field at the vehicle; ``BAD_RADIUS`` when it is outside ``[COMPASS_MIN_SCALE_FACTOR, COMPASS_MAX_SCALE_FACTOR]``
   = ``[1/1.5, 1.5]`` (``CompassCalibrator.h``; 0.85-1.4 in older versions). The code's comment says "30 %", the
   constants allow −33 % to +50 %.
3. ``calculate_orientation()``, with the attitude at each sample: for every rotation ``R`` of the table (26, 27,
   38 and 41 skipped: duplicates, the Solo's leg, PITCH_7), the earth-frame field ``A R R_declᵀ (x + ofs)`` and
   its variance about its mean; the lowest wins, the confidence is the second lowest over it. It passes when the
   winner is the declared orientation, or the confidence exceeds 4, or (only right angles considered) their
   confidence exceeds 2 (``COMPASS_AUTO_ROT`` 3 accepts 2 for every rotation). A winner other than the
   declared one is ``BAD_ORIENTATION`` for an internal compass or without ``COMPASS_AUTO_ROT`` 2/3.

**PX4** (``src/modules/commander/mag_calibration.cpp``, ``check_calibration_result``): every parameter finite
(``sphere NaN``); the radius in ``[0.2, 0.7)`` G (``sphere radius invalid``); the radius and the diagonal
positive (``non-positive scale``); an offset above 1.3 G is a warning (``large offsets``: the sensor saturates in
some directions), not a failure. ``COM_ARM_MAG_ANG`` is the pre-arm consistency check of
:mod:`magfit.consistency`.

Each test gives its value, the limit with the parameter that sets it, and whether it passes; each failure is a
:class:`magfit.findings.Reason` with code ``firmware_check`` and what to do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._validation import as_samples
from .calibration import Calibration
from .errors import MagfitError
from .findings import Reason, ReasonList
from .rotations import polar_decomposition, standard_rotations
from .units import conversion_factor, get_unit

if TYPE_CHECKING:
    from .pipeline import FileCalibration
    from .sources.calibration_messages import CalibrationMessages

__all__ = [
    "AcceptanceTest",
    "FirmwareReplay",
    "LogExplanation",
    "explain_log",
    "replay_ardupilot",
    "replay_px4",
]

#: ArduPilot's defaults: COMPASS_CAL_FIT (AP_COMPASS_CALIBRATION_FITNESS_DEFAULT), COMPASS_OFFS_MAX
#: (AP_COMPASS_OFFSETS_MAX_DEFAULT), the radius bounds (FIELD_RADIUS_MIN/MAX, mG), the scale factor bounds.
ARDUPILOT_FITNESS = 16.0
ARDUPILOT_OFFSETS_MAX = 1800.0
ARDUPILOT_RADIUS = (150.0, 950.0)
ARDUPILOT_SCALE = (1.0 / 1.5, 1.5)
ARDUPILOT_OLD_SCALE = (0.85, 1.4)
#: CompassCalibrator::auto_rotation_index skips these table entries.
ARDUPILOT_SKIPPED_ROTATIONS = frozenset({26, 27, 38, 41})
#: PX4's check_calibration_result: the radius bounds (G) and the offset that warns (G).
PX4_RADIUS = (0.2, 0.7)
PX4_LARGE_OFFSET = 1.3


@dataclass(frozen=True)
class AcceptanceTest:
    """One of a firmware's acceptance tests, replayed.

    Attributes
    ----------
    name : str
        ``fitness``, ``radius``, ``field against the model``, ``offsets``, ``diagonal``, ``off-diagonal``,
        ``orientation``, ``finite``, ``scale``.
    passed : bool or None
        None when it cannot be replayed (``value`` says why: no physical unit, no model field, no attitude).
    value : str
        What the samples give, with its unit.
    limit : str
        The firmware's limit and the parameter or constant that sets it.
    failure : str
        What the firmware reports when it fails (``FAILED``, ``BAD_RADIUS``, a warning).
    margin : str
        By how much it passes or fails, in words (empty when not replayed).
    """

    name: str
    passed: bool | None
    value: str
    limit: str
    failure: str
    margin: str = ""


@dataclass(frozen=True)
class FirmwareReplay:
    """A firmware's acceptance tests replayed on one compass.

    Attributes
    ----------
    firmware : str
        ``"ardupilot"`` or ``"px4"``.
    sensor : str
        The compass.
    tests : tuple of AcceptanceTest
    reasons : tuple of Reason
        One per failed test, code ``firmware_check``, with what to do.
    status : str
        What the firmware would report: ``SUCCESS``, ``FAILED``, ``BAD_RADIUS``, ``BAD_ORIENTATION`` (ArduPilot,
        in its order of tests) or ``OK`` / ``FAILED`` (PX4).
    """

    firmware: str
    sensor: str
    tests: tuple[AcceptanceTest, ...]
    reasons: tuple[Reason, ...] = ()
    status: str = "SUCCESS"

    @property
    def passed(self) -> bool:
        """Every test replayed passes (False when they could not be replayed)."""
        return self.status in ("SUCCESS", "OK")


@dataclass(frozen=True)
class LogExplanation:
    """:func:`explain_log`'s answer: the replays, and what the log's firmware itself said.

    Attributes
    ----------
    replays : tuple of FirmwareReplay
        One per compass fitted (and per firmware when the log's firmware is unknown).
    said : CalibrationMessages or None
        The firmware's own reports, messages and settings found in the log.
    notes : tuple of str
        Where the settings and the model field came from.
    """

    replays: tuple[FirmwareReplay, ...]
    said: CalibrationMessages | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)


def _factor(unit: str, target: str) -> float | None:
    try:
        return conversion_factor(unit, target) if unit and get_unit(unit).is_physical else None
    except MagfitError:
        return None


def _ratio(value: float, limit: float) -> str:
    return f"{value / limit:.2f}× the limit" if limit else ""


def replay_ardupilot(
    samples: ArrayLike,
    calibration: Calibration,
    *,
    sensor: str = "",
    unit: str | None = None,
    expected_field: float | None = None,
    tolerance: float = ARDUPILOT_FITNESS,
    offsets_max: float = ARDUPILOT_OFFSETS_MAX,
    attitude: ArrayLike | None = None,
    orientation: int = 0,
    external: bool = True,
    auto_rot: int = 2,
    scale_limits: tuple[float, float] = ARDUPILOT_SCALE,
    parameter_suffix: str = "",
) -> FirmwareReplay:
    """ArduPilot's ``CompassCalibrator`` tests on ``samples`` with ``calibration``'s parameters (module docstring).

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        The raw field as the calibrator sees it: after the declared orientation, before any offset (what
        :meth:`magfit.sources.Source.read` gives for an ArduPilot log).
    calibration : Calibration
        magfit's fit of them.
    unit : str, optional
        The samples' unit (default ``calibration.unit``); the limits are in mG.
    expected_field : float, optional
        The World Magnetic Model's total field at the vehicle, in ``unit`` (``fix_radius`` is skipped without it,
        as the firmware skips it without a GNSS fix).
    tolerance, offsets_max : float
        ``COMPASS_CAL_FIT`` and ``COMPASS_OFFS_MAX`` (mG).
    attitude : array_like, shape (N, 3, 3), optional
        Body -> NED at each sample (``calculate_orientation`` is skipped without it).
    orientation : int
        The declared ``COMPASS_ORIENT*`` (the samples already carry it).
    external, auto_rot : bool, int
        ``COMPASS_EXTERNAL*`` and ``COMPASS_AUTO_ROT``.
    scale_limits : (float, float)
        ``COMPASS_MIN/MAX_SCALE_FACTOR``.
    parameter_suffix : str
        ``""``, ``"2"`` or ``"3"``: the compass's parameter names in the advice.
    """
    x = as_samples(samples)
    unit = calibration.unit if unit is None else unit
    to_mg = _factor(unit or "", "mG")
    tests: list[AcceptanceTest] = []
    reasons = ReasonList()
    status = "SUCCESS"
    _, symmetric = polar_decomposition(calibration.matrix)
    radius = float(calibration.field_strength)
    residual = radius - np.linalg.norm((x - calibration.offset) @ symmetric.T, axis=1)
    if to_mg is None:
        tests.append(
            AcceptanceTest(
                "fitness", None, f"not replayed: the samples' unit ({unit or 'unknown'}) is not physical", "", "FAILED"
            )
        )
        return FirmwareReplay("ardupilot", sensor, tuple(tests), (), "unknown")
    fitness = float(np.sqrt(np.mean(residual**2))) * to_mg
    r = radius * to_mg
    ofs = -np.asarray(calibration.offset) * to_mg
    diag, off = np.diag(symmetric), symmetric[[0, 0, 1], [1, 2, 2]]

    def add(test: AcceptanceTest, words: str, remedy: tuple[tuple[str, str], ...] = ()) -> None:
        tests.append(test)
        if test.passed is False:
            reasons.add("firmware_check", words, remedy)

    add(
        AcceptanceTest(
            "fitness", fitness <= tolerance, f"{fitness:.1f} mG RMS", f"≤ COMPASS_CAL_FIT {tolerance:g} mG", "FAILED",
            _ratio(fitness, tolerance),
        ),
        f"ArduPilot's fitness test fails: the samples lie {fitness:.1f} mG RMS from the fitted ellipsoid, above "
        f"COMPASS_CAL_FIT {tolerance:g} mG: a field that changes during the calibration (motors or power on, iron "
        "moving nearby, a compass that is loose); calibrate outdoors on battery only, away from metal and cars",
    )  # fmt: skip
    low, high = ARDUPILOT_RADIUS
    add(
        AcceptanceTest(
            "radius", low < r < high, f"{r:.0f} mG", f"between {low:.0f} and {high:.0f} mG (FIELD_RADIUS_MIN/MAX)",
            "FAILED", f"{r - high:+.0f} mG beyond" if r >= high else f"{low - r:+.0f} mG below" if r <= low else "",
        ),
        f"ArduPilot's radius test fails: the fitted field is {r:.0f} mG, outside {low:.0f}-{high:.0f} mG: the "
        "compass's scale is wrong (its driver or its range setting), or it is not a compass at all",
    )  # fmt: skip
    largest = float(np.max(np.abs(ofs)))
    add(
        AcceptanceTest(
            "offsets", largest < offsets_max, f"largest |offset| {largest:.0f} mG",
            f"< COMPASS_OFFS_MAX {offsets_max:g} mG", "FAILED", _ratio(largest, offsets_max),
        ),
        f"ArduPilot's offsets test fails: an offset of {largest:.0f} mG exceeds COMPASS_OFFS_MAX {offsets_max:g}: "
        "something magnetised sits near the compass (a magnet, a steel screw, the battery strap); move the compass "
        "away from it. Raising COMPASS_OFFS_MAX only hides it",
    )  # fmt: skip
    diag_ok = bool(np.all((diag > 0.2) & (diag < 5.0)))
    add(
        AcceptanceTest(
            "diagonal", diag_ok, "(" + ", ".join(f"{v:.3f}" for v in diag) + ")", "each in (0.2, 5)", "FAILED"
        ),
        "ArduPilot's diagonal test fails: the soft-iron scales are beyond what it accepts",
    )
    off_ok = bool(np.all(np.abs(off) < 1.0))
    add(
        AcceptanceTest(
            "off-diagonal", off_ok, "(" + ", ".join(f"{v:.3f}" for v in off) + ")", "each |.| < 1", "FAILED"
        ),
        "ArduPilot's off-diagonal test fails",
    )
    if not reasons:
        status = "SUCCESS"
    else:
        status = "FAILED"
    if expected_field is None or not math.isfinite(expected_field) or expected_field <= 0:
        tests.append(
            AcceptanceTest(
                "field against the model", None,
                "not replayed: no model field (the firmware skips it without a GNSS fix)",
                f"expected / radius within [{scale_limits[0]:.3f}, {scale_limits[1]:.2f}]", "BAD_RADIUS",
            )
        )  # fmt: skip
    else:
        expected = expected_field * to_mg
        correction = expected / r
        ok = scale_limits[0] <= correction <= scale_limits[1]
        add(
            AcceptanceTest(
                "field against the model", ok, f"radius {r:.0f} mG, model {expected:.0f} mG (scale {correction:.3f})",
                f"expected / radius within [{scale_limits[0]:.3f}, {scale_limits[1]:.2f}] "
                "(COMPASS_MIN/MAX_SCALE_FACTOR)", "BAD_RADIUS", f"{100 * (r / expected - 1):+.0f} % from the model",
            ),
            f"ArduPilot's radius check against the World Magnetic Model fails (BAD_RADIUS): the fitted field "
            f"{r:.0f} mG is {100 * (r / expected - 1):+.0f} % from the model's {expected:.0f} mG here: the compass's "
            "scale is wrong, or it was calibrated in a disturbed field (indoors, near steel): calibrate outdoors",
        )  # fmt: skip
        if not ok and status == "SUCCESS":
            status = "BAD_RADIUS"
    if attitude is None:
        tests.append(
            AcceptanceTest(
                "orientation", None, "not replayed: no attitude in the log", "confidence > 2 or 4", "BAD_ORIENTATION"
            )
        )
    else:
        test, words, remedy, bad = _orientation_test(
            x, np.asarray(calibration.offset), np.asarray(attitude, dtype=np.float64), orientation, external, auto_rot,
            parameter_suffix,
        )  # fmt: skip
        add(test, words, remedy)
        if bad and status == "SUCCESS":
            status = "BAD_ORIENTATION"
    return FirmwareReplay("ardupilot", sensor, tuple(tests), tuple(reasons), status)


def _orientation_test(
    x: NDArray[np.float64],
    offset: NDArray[np.float64],
    attitude: NDArray[np.float64],
    orientation: int,
    external: bool,
    auto_rot: int,
    suffix: str,
) -> tuple[AcceptanceTest, str, tuple[tuple[str, str], ...], bool]:
    """CompassCalibrator::calculate_orientation on (at most 2 000 of) the samples."""
    table = standard_rotations("ardupilot")
    if orientation not in table:
        test = AcceptanceTest(
            "orientation", None, f"not replayed: COMPASS_ORIENT{suffix} {orientation} is custom", "", ""
        )
        return test, "", (), False
    stride = max(1, len(x) // 2000)
    v = (x - offset)[::stride]  # sample + ofs, ofs = −offset
    a = attitude[::stride]
    declared = table[orientation].matrix
    candidates = [k for k in sorted(table) if k not in ARDUPILOT_SKIPPED_ROTATIONS]
    variance = {}
    for k in candidates:
        turned = v @ (table[k].matrix @ declared.T).T
        earth = np.einsum("nij,nj->ni", a, turned)
        variance[k] = float(np.mean(np.sum((earth - earth.mean(axis=0)) ** 2, axis=1)))
    right = [k for k in candidates if np.all(np.isin(np.round(table[k].matrix, 9), (-1.0, 0.0, 1.0)))]
    best = min(candidates, key=lambda k: variance[k])
    second = min((k for k in candidates if k != best), key=lambda k: variance[k])
    confidence = variance[second] / variance[best] if variance[best] > 0 else math.inf
    best_90 = min(right, key=lambda k: variance[k])
    second_90 = min((k for k in right if k != best_90), key=lambda k: variance[k])
    passed = best == orientation or confidence > 4.0 or (auto_rot == 3 and confidence > 2.0)
    rule = "the declared one wins" if best == orientation else "confidence > 4"
    if not passed:
        confidence = variance[second_90] / variance[best_90] if variance[best_90] > 0 else math.inf
        passed = confidence > 2.0
        best = best_90
        rule = "right angles only, confidence > 2"
    fixes = external and auto_rot in (2, 3)
    bad = not passed or (best != orientation and not fixes)
    name = table[best].name
    value = f"best {name} ({best}), confidence {confidence:.1f}; declared {table[orientation].name} ({orientation})"
    limit = "the declared rotation wins, or confidence > 4 (right angles: > 2)"
    margin = rule if passed else ""
    if passed and best != orientation and fixes:
        margin = f"{rule}; the firmware sets COMPASS_ORIENT{suffix} {best} itself (COMPASS_AUTO_ROT {auto_rot})"
    test = AcceptanceTest("orientation", not bad, value, limit, "BAD_ORIENTATION", margin)
    if not passed:
        words = (
            f"ArduPilot's orientation test fails (BAD_ORIENTATION): no rotation stands out (best {name}, confidence "
            f"{confidence:.1f} ≤ 2): the attitude and the compass disagree whatever its rotation; tilt the vehicle "
            "more during the calibration, and check that the autopilot's own orientation (AHRS_ORIENTATION) is right"
        )
        return test, words, (), bad
    if best != orientation and not fixes:
        words = (
            f"ArduPilot's orientation test finds the compass mounted as {name} ({best}), not as declared "
            f"({table[orientation].name}): an {'external' if external else 'internal'} compass it will not fix "
            f"itself (COMPASS_AUTO_ROT {auto_rot}); set COMPASS_ORIENT{suffix} {best}"
        )
        return test, words, ((f"COMPASS_ORIENT{suffix}", str(best)),), bad
    return test, "", (), bad


def replay_px4(
    samples: ArrayLike, calibration: Calibration, *, sensor: str = "", unit: str | None = None
) -> FirmwareReplay:
    """PX4's ``check_calibration_result`` on ``calibration``'s parameters (module docstring); the limits are in G."""
    as_samples(samples)
    unit = calibration.unit if unit is None else unit
    to_g = _factor(unit or "", "G")
    tests: list[AcceptanceTest] = []
    reasons = ReasonList()
    _, symmetric = polar_decomposition(calibration.matrix)
    values = [*np.asarray(calibration.offset), calibration.field_strength, *symmetric[np.triu_indices(3)]]
    finite = bool(np.all(np.isfinite(values)))
    tests.append(
        AcceptanceTest("finite", finite, "every parameter finite" if finite else "a NaN", "finite", "sphere NaN")
    )
    if to_g is None:
        tests.append(
            AcceptanceTest("radius", None, f"not replayed: the unit ({unit or 'unknown'}) is not physical", "", "")
        )
        return FirmwareReplay("px4", sensor, tuple(tests), (), "unknown")
    radius = float(calibration.field_strength) * to_g
    low, high = PX4_RADIUS
    ok = low <= radius < high
    tests.append(
        AcceptanceTest(
            "radius", ok, f"{radius:.3f} G", f"in [{low}, {high}) G", "Retry calibration (sphere radius invalid)",
            "" if ok else f"{radius - (high if radius >= high else low):+.3f} G beyond",
        )
    )  # fmt: skip
    if not ok:
        reasons.add(
            "firmware_check",
            f"PX4's radius test fails ('sphere radius invalid {radius:.3f}'): the fitted field is outside "
            f"{low}-{high} G: the compass's scale is wrong, or the calibration was done in a disturbed field",
        )
    diag = np.diag(symmetric)
    positive = bool(np.all(diag > 0) and radius > 0)
    tests.append(
        AcceptanceTest("scale", positive, "(" + ", ".join(f"{v:.3f}" for v in diag) + ")", "> 0", "non-positive scale")
    )
    largest = float(np.max(np.abs(calibration.offset))) * to_g
    tests.append(
        AcceptanceTest(
            "offsets", largest <= PX4_LARGE_OFFSET, f"largest |offset| {largest:.3f} G",
            f"≤ {PX4_LARGE_OFFSET} G (a warning, not a failure)", "Warning: mag with large offsets",
        )
    )  # fmt: skip
    status = "FAILED" if reasons else "OK"
    return FirmwareReplay("px4", sensor, tuple(tests), tuple(reasons), status)


def explain_log(result: FileCalibration) -> LogExplanation:
    """Replay the firmware's acceptance tests on each compass :func:`magfit.calibrate_file` fitted in a log, with
    the log's own settings (``COMPASS_CAL_FIT``, ``COMPASS_OFFS_MAX``, the orientations), the World Magnetic
    Model's field when the fit had it, and the attitude when the log has it; and gather what the firmware itself
    said (:func:`magfit.sources.calibration_messages.read_calibration_messages`).

    Raises
    ------
    DataFileError
        The log cannot be read again.
    """
    from .sources import open_source
    from .sources.calibration_messages import read_calibration_messages

    source = open_source(result.path)
    said = read_calibration_messages(result.path)
    settings = said.settings
    firmware = {"dataflash": "ardupilot", "tlog": "ardupilot", "mavlogdump": "ardupilot", "ulog": "px4"}.get(
        source.kind
    )
    notes = []
    if settings:
        notes.append("settings from the log: " + ", ".join(f"{k} {v:g}" for k, v in sorted(settings.items())))
    if firmware == "ardupilot":
        missing = [name for name in ("COMPASS_CAL_FIT", "COMPASS_OFFS_MAX", "COMPASS_AUTO_ROT") if name not in settings]
        if missing:
            notes.append(
                f"{', '.join(missing)} not in the log's parameters: today's defaults assumed (a firmware without "
                "COMPASS_AUTO_ROT, before 4.0, has no orientation test)"
            )
    replays = []
    for compass in result.compasses:
        if compass.magnetometer is None:
            continue
        sensor = compass.magnetometer.id
        attitude = None
        try:
            motion = source.read_motion(sensor)
            samples, attitude = motion.samples, motion.attitude
        except MagfitError:
            samples = source.read(sensor).samples
        model = compass.model_field or result.model_field
        expected = None
        if model is not None and compass.calibration.unit:
            try:
                expected = model.field.total_in(compass.calibration.unit)
            except MagfitError:
                expected = None
        slot = compass.magnetometer.slot or 0
        suffix = "" if slot == 0 else str(slot + 1)
        if firmware in (None, "ardupilot"):
            replays.append(
                replay_ardupilot(
                    samples, compass.calibration, sensor=sensor, expected_field=expected,
                    tolerance=settings.get("COMPASS_CAL_FIT", ARDUPILOT_FITNESS),
                    offsets_max=settings.get("COMPASS_OFFS_MAX", ARDUPILOT_OFFSETS_MAX), attitude=attitude,
                    orientation=int(settings.get(f"COMPASS_ORIENT{suffix}", 0)),
                    external=bool(settings.get("COMPASS_EXTERNAL" if slot == 0 else f"COMPASS_EXTERN{suffix}", 1)),
                    auto_rot=int(settings.get("COMPASS_AUTO_ROT", 2)), parameter_suffix=suffix,
                )
            )  # fmt: skip
        if firmware in (None, "px4"):
            replays.append(replay_px4(samples, compass.calibration, sensor=sensor))
    return LogExplanation(tuple(replays), said, tuple(notes))
