"""Accuracy of the calibrations that use what a vehicle knows, against a known truth.

Run through the accuracy benchmark (in the peers' environment, for MAGYC)::

    benchmarks/.peers-venv/bin/python benchmarks/accuracy.py --vehicle

Each case is a simulated vehicle (:func:`magfit.vehicle.simulate_vehicle`): a flight with turns banked up to
±15°, a car on sloping roads, a boat rolling on a nearly constant heading, or a hand-held tumble; a mild
random sensor (scales ±2 %, symmetric cross terms ±1 %, hard iron up to 0.4 B) mounted at a random angle
of 5-35° about a random axis; the attitude the vehicle logs lagging 0.1 s behind the truth and wandering
by 0.2, 0.5 or 1° per axis (correlated over 5 s, as an estimator's error is); gyroscope noise and bias,
accelerometer noise. Every method is fitted to the same recording.

Metrics (per trial, then the RMS over the trials of a case)
------------------------------------------------------------
heading error
    The fitted calibration applied to the noise-free readings of the recording (``sim.clean``); each
    calibrated body-frame vector is turned into the world with the TRUE attitude and its heading
    ``atan2(east, north)`` compared with that of the true field: the RMS over the recording's samples, so
    over the attitudes the vehicle actually had. A calibration whose ``frame`` is ``"sensor"`` (every
    magnitude-only method) gives the field in the magnetometer's axes and cannot know the mounting: it is
    scored as a user would use it (sensor axes taken as the vehicle's, the column "as given") and with the
    TRUE mounting applied (``mounting @ corrected``, the column "true mounting"): the best a magnitude-only
    fit can do if the mounting were known exactly. The truth's soft iron is symmetric, so the symmetric
    root that a magnitude-only fit returns is the truth's own matrix when the fit is exact.
alignment error
    The angle of the rotation between the fitted and the true magnetometer-to-vehicle rotation. For a
    calibration in the vehicle frame, the fitted rotation is the orthogonal polar factor of its matrix
    (``matrix = Q P``, P symmetric positive definite): the truth's matrix is ``mounting W⁻¹`` with W
    symmetric, whose polar factor is exactly the mounting.
offset error
    ``|V_fit − V_true| / B``.
stated one-sigma
    The heading one-sigma a magfit fit states (level attitude, every heading). Where ``auto`` answers, it must
    cover the heading error with the true mounting on 90 % of the trials; its refusals are counted beside (a
    boat holding its heading: the samples cannot bound what the distortion along the directions never seen
    does to the heading, and the refusal names the methods that use what the vehicle knows).

``vector`` and ``gyro`` get every stream of the recording their options take: the reference, the time stamps,
the gyro and the accelerometer (``sim.accel``, specific force in the vehicle frame: where the vehicle is
still or slow it sees gravity alone, which pins the mounting's tilt better than the erring attitude). The
``vector (no accel)`` column is ``vector`` given the reference and the time stamps only, as before the
accelerometer was used: the difference between the two columns is what gravity adds. (A checkout whose
``vector`` does not take ``accel=`` has no such column; neither method is given a stream it does not take.)

The plain regression (``regression`` column) is no magfit method: the ordinary least-squares fit of
``raw = G r + V`` to the logged reference ``r`` (12 numbers, no lag, no noise model), the yardstick of
the real-log target. MAGYC's gyro-aided methods (``magyc.magyc_*``) get the samples, the gyro and
the time stamps; their calibrated field is in the gyroscope's (the vehicle's) axes, so they are scored
"as given" in the vehicle frame.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from _common import (
    Ratio,
    Target,
    failure_message,
    kept_details,
    mild_distortion,
    note,
    paired_ratio,
    pass_fail,
    verdict_of,
    versions,
)
from _common import report_json as report_json  # accuracy.py writes the vehicle report with it
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

import magfit
from magfit.vehicle import VehicleSimulation, simulate_vehicle

#: Magnitude-only methods run on every case (forced, as in the main grid; ``auto`` unforced).
MAGNITUDE_METHODS = ("sphere", "diag", "als", "ml", "auto")
NOT_FORCED = ("auto",)
REGRESSION = "regression"
VECTOR = "vector"
#: ``vector`` without the accelerometer (the reference and the time stamps only): what gravity adds.
VECTOR_NO_ACCEL = "vector (no accel)"
#: The magfit method behind each column not named after one.
METHOD_OF = {VECTOR_NO_ACCEL: VECTOR}
#: magfit's gyro-aided method.
GYRO = "gyro"
#: MAGYC's gyro-aided methods (magyc 1.0.0, Rodríguez et al. 2024).
MAGYC_METHODS = ("magyc_ls", "magyc_nls", "magyc_bfg", "magyc_ifg")
#: ``magfit.alignment.align`` on the samples corrected by the true magnitude-only calibration (the
#: alignment's own error) and by ``auto``'s (what a user gets; nothing when auto refuses).
ALIGN_TRUE = "align (true cal)"
ALIGN_AUTO = "align (auto cal)"
#: ... and by the magnitude-only part of the trial's ``gyro`` fit (what ``magfit align`` starts from with a gyro).
ALIGN_GYRO = "align (gyro cal)"
MOUNTING_RANGE_DEG = (5.0, 35.0)


@dataclass(frozen=True)
class VehicleCase:
    """One simulated vehicle scenario, run for ``trials`` seeded trials (see the module docstring)."""

    name: str
    motion: str
    attitude_noise_deg: float
    trials: int
    n: int = 6000
    rate_hz: float = 10.0
    lag_s: float = 0.1
    #: Range of the mounting angle (degrees, about a random axis); (0, 0): the magnetometer is aligned.
    mounting_deg: tuple[float, float] = MOUNTING_RANGE_DEG
    noise: float = 0.005  # magnetometer noise per axis, fraction of B
    max_tilt_deg: float = 15.0
    gyro_noise: float = 0.002  # rad/s per sample
    gyro_bias: float = 0.01  # rad/s, each axis drawn in ±this
    accel_noise: float = 0.05  # m/s²
    inclination_deg: float = 64.0
    #: Run magfit's gyro-aided method here. It does not read the attitude (and took 10-25 s a fit on these
    #: recordings at first): by default it runs on one attitude error per motion (1°) and on the tumble.
    gyro: bool = True
    #: MAGYC's methods run on this case (by default on the tumble, its own kind of data, only).
    magyc: tuple[str, ...] = ()

    def simulate(self, root_seed: int, trial: int) -> VehicleSimulation:
        """The recording of one trial: its own sensor, mounting, declination and trajectory.

        Seeded by the motion, not the case: trial k of every attitude error of a motion is the same vehicle on
        the same trajectory with the same magnetometer noise (the error draws are scaled, not redrawn), so
        the cases of a motion differ only in the attitude error logged: paired comparisons across them.
        """
        rng = np.random.default_rng([root_seed, _key(self.motion), trial])
        soft_iron, hard_iron = mild_distortion(rng)
        axis = rng.normal(size=3)
        angle = np.radians(rng.uniform(*self.mounting_deg))
        mounting = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
        return simulate_vehicle(
            self.n,
            self.motion,
            rate_hz=self.rate_hz,
            soft_iron=soft_iron,
            hard_iron=hard_iron,
            mounting=mounting,
            inclination_deg=self.inclination_deg,
            declination_deg=float(rng.uniform(-20.0, 20.0)),
            noise=self.noise,
            max_tilt_deg=self.max_tilt_deg,
            attitude_noise_deg=self.attitude_noise_deg,
            lag_s=self.lag_s,
            gyro_noise=self.gyro_noise,
            gyro_bias=rng.uniform(-self.gyro_bias, self.gyro_bias, 3),
            accel_noise=self.accel_noise,
            seed=rng,
        )


def _key(name: str) -> int:
    return zlib.crc32(name.encode())


def vehicle_grid(trials_scale: float = 1.0) -> list[VehicleCase]:
    """The scenarios: flight, car and boat at three attitude noises; a tumble for the gyro-aided fits."""
    # 8 trials: the default run stays under 5 minutes (3 trials took 74 s with the gyro-aided fits at 1-3 s
    # each); the ratios carry their standard errors.
    trials = max(1, round(8 * trials_scale))
    cases = [
        VehicleCase(f"{motion}, attitude ±{noise:g}°", motion, noise, trials, gyro=noise == 1.0)
        for motion in ("flight", "car", "boat")
        for noise in (0.2, 0.5, 1.0)
    ]
    # MAGYC's methods take 6-17 s a fit on a 6000-sample flight (magyc_bfg's factor graph 470 s) and reach
    # 4-7° there (one trial, flight at 1°): on the restricted motions they are not run by default.
    # MAGYC's own kind of data: a hand-held tumble, the magnetometer in the gyro's axes, 50 Hz.
    cases.append(VehicleCase("tumble, attitude ±0.5°", "tumble", 0.5, trials, n=6000, rate_hz=50.0,
                             mounting_deg=(0.0, 0.0), magyc=MAGYC_METHODS))  # fmt: skip
    return cases


def vehicle_smoke_grid() -> list[VehicleCase]:
    """Two tiny cases (what the test runs): a flight and a tumble, two trials each."""
    return [
        VehicleCase("flight, attitude ±1°", "flight", 1.0, 2, n=1500, gyro=False),
        VehicleCase("tumble, attitude ±0.5°", "tumble", 0.5, 2, n=1500, rate_hz=50.0, mounting_deg=(0.0, 0.0)),
    ]


# ====================================================================== metrics


def _wrapped_deg(angle: NDArray[np.float64]) -> NDArray[np.float64]:
    return (np.degrees(angle) + 180.0) % 360.0 - 180.0


def heading_error_deg(body: NDArray[np.float64], simulation: VehicleSimulation) -> float:
    """RMS heading error (degrees) of body-frame field vectors ``body`` (N, 3) of the recording's samples.

    Each vector is turned into the world (NED) with the TRUE attitude; its heading ``atan2(east, north)``
    is compared with the true field's.
    """
    world = np.einsum("kij,kj->ki", simulation.attitude, body)
    truth = np.arctan2(simulation.field_world[1], simulation.field_world[0])
    return float(np.sqrt(np.mean(_wrapped_deg(np.arctan2(world[:, 1], world[:, 0]) - truth) ** 2)))


def rotation_angle_deg(rotation: NDArray[np.float64]) -> float:
    """The angle (degrees) of a rotation matrix: ``atan2(sin θ, cos θ)`` from its skew part and trace (the
    arccos of the trace alone loses half the digits near 0)."""
    skew = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    return float(np.degrees(np.arctan2(np.linalg.norm(skew) / 2.0, (np.trace(rotation) - 1.0) / 2.0)))


def polar_rotation(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """The orthogonal factor Q of ``matrix = Q P`` (P symmetric positive definite)."""
    u, _, vt = np.linalg.svd(matrix)
    return np.asarray(u @ vt, dtype=np.float64)


def alignment_error_deg(fitted: NDArray[np.float64], simulation: VehicleSimulation) -> float:
    """Angle (degrees) between a fitted magnetometer-to-vehicle rotation and the true mounting."""
    return rotation_angle_deg(fitted @ simulation.mounting.T)


# ====================================================================== the methods


@dataclass
class VehicleOutcome:
    """The scores of one method on one trial (or the reason it failed)."""

    heading_deg: float | None = None
    #: Sensor-frame calibrations: the heading error with the true mounting applied (else = heading_deg).
    heading_mounted_deg: float | None = None
    alignment_deg: float | None = None
    offset_error: float | None = None
    frame: str | None = None
    seconds: float | None = None
    error: str | None = None
    verdict: str | None = None
    verdict_reason: str | None = None
    #: Method facts kept from ``details`` (the estimated lag, the chosen model ...).
    details: dict[str, Any] | None = None
    #: The heading one-sigma the fit states (``diagnostics.uncertainty.heading_sigma_deg``), degrees.
    stated_heading_deg: float | None = None


#: A method run on a simulated recording (the samples and whatever else of the recording it uses).
Fitter = Callable[[VehicleSimulation], magfit.Calibration]


def _magfit(name: str, **extra: Callable[[VehicleSimulation], Any]) -> Fitter:
    forced = name not in NOT_FORCED

    def run(simulation: VehicleSimulation) -> magfit.Calibration:
        options = {key: make(simulation) for key, make in extra.items()}
        return magfit.fit(simulation.samples, method=name, allow_undetermined=forced, **options)

    return run


#: The recording's streams, by the name of the option that takes them.
STREAMS: dict[str, Callable[[VehicleSimulation], Any]] = {
    "reference": lambda s: s.reference,
    "time_s": lambda s: s.time_s,
    "gyro": lambda s: s.gyro,
    "accel": lambda s: s.accel,
}


def _taken(name: str, without: Sequence[str] = ()) -> dict[str, Callable[[VehicleSimulation], Any]]:
    """The streams method ``name`` takes (its options), but those in ``without``."""
    options = magfit.METHODS[name].options
    return {key: make for key, make in STREAMS.items() if key in options and key not in without}


def regression(simulation: VehicleSimulation) -> magfit.Calibration:
    """The plain regression on the simulated recording's logged reference (see :func:`plain_regression`)."""
    return plain_regression(simulation.samples, simulation.reference)


def plain_regression(samples: NDArray[np.float64], reference: NDArray[np.float64]) -> magfit.Calibration:
    """Ordinary least squares of ``raw = G r + V`` on the reference ``r`` (N, 3): matrix G⁻¹, offset V."""
    design = np.column_stack([reference, np.ones(len(reference))])
    solution, *_ = np.linalg.lstsq(design, samples, rcond=None)
    gain, offset = solution[:3].T, solution[3]  # raw_i = Σ_j G_ij r_j + V_i
    correction = np.linalg.inv(gain)
    scale = abs(np.linalg.det(correction)) ** (1.0 / 3.0)
    field_strength = float(np.median(np.linalg.norm(reference, axis=1)))
    return magfit.Calibration(REGRESSION, offset, correction / scale, field_strength / scale, frame="vehicle")


def _magyc(function: str) -> Fitter:
    def run(simulation: VehicleSimulation) -> magfit.Calibration:
        from peers import PeerFailure, _import, _quiet, calibration_from_correction

        magyc = _import("magyc", "magyc")
        with _quiet(), np.errstate(all="ignore"):
            result = getattr(magyc, function)(simulation.samples.copy(), simulation.gyro.copy(),
                                              simulation.time_s.copy())  # fmt: skip
        hard_iron, soft_iron = result[0], result[1]
        # Documented: calibrated = inv(soft_iron) @ (m − hard_iron), in the gyroscope's axes (applied by
        # us row by row: magyc's own output goes through reshape(3, -1), which scrambles the axes).
        try:
            correction = np.linalg.inv(np.real_if_close(soft_iron))
        except np.linalg.LinAlgError:
            raise PeerFailure("returned a singular soft-iron matrix") from None
        fitted = calibration_from_correction(f"magyc.{function}", hard_iron, correction, None, simulation.samples)
        return magfit.Calibration(fitted.method, fitted.offset, fitted.matrix, fitted.field_strength, frame="vehicle")

    return run


def _takes_accel(name: str) -> bool:
    return name in magfit.METHODS and "accel" in magfit.METHODS[name].options


def method_table(methods: Sequence[str] | None = None, peers: bool = True) -> dict[str, Fitter]:
    """Every fitter that exists in this checkout, by column name (a method not yet in magfit is left out)."""
    table: dict[str, Fitter] = {name: _magfit(name) for name in MAGNITUDE_METHODS if name in magfit.METHODS}
    table[REGRESSION] = regression
    if VECTOR in magfit.METHODS:
        table[VECTOR] = _magfit(VECTOR, **_taken(VECTOR))
        if _takes_accel(VECTOR):
            table[VECTOR_NO_ACCEL] = _magfit(VECTOR, **_taken(VECTOR, without=("accel", "gyro")))
    if GYRO in magfit.METHODS:
        table[GYRO] = _magfit(GYRO, **_taken(GYRO))
    if peers:
        for function in MAGYC_METHODS:
            table[f"magyc.{function}"] = _magyc(function)
    wanted = None if methods is None else set(methods)
    return {name: fitter for name, fitter in table.items() if wanted is None or {name, METHOD_OF.get(name)} & wanted}


def alignment_available() -> bool:
    try:
        import magfit.alignment  # noqa: F401  (the alignment from gravity; may not exist yet)
    except ImportError:
        return False
    return True


def fit_alignment(simulation: VehicleSimulation, calibration: magfit.Calibration) -> NDArray[np.float64]:
    """``magfit.alignment.align`` on the samples corrected by a magnitude-only ``calibration``, given the true
    inclination, the gyro and the time: the fitted magnetometer-to-vehicle rotation (``body = R @ sensor``)."""
    from magfit.alignment import align

    f = simulation.field_world
    result = align(
        calibration.apply(simulation.samples),
        simulation.accel,
        inclination_deg=float(np.degrees(np.arctan2(f[2], np.hypot(f[0], f[1])))),
        gyro=simulation.gyro,
        time_s=simulation.time_s,
    )
    return np.asarray(result.matrix, dtype=np.float64)


# ====================================================================== running a case


def score(calibration: magfit.Calibration, simulation: VehicleSimulation) -> VehicleOutcome:
    corrected = calibration.apply(simulation.clean)
    report = calibration.diagnostics
    outcome = VehicleOutcome(
        heading_deg=heading_error_deg(corrected, simulation),
        offset_error=float(np.linalg.norm(calibration.offset - simulation.hard_iron)
                           / simulation.truth.field_strength),
        frame=calibration.frame,
        stated_heading_deg=None if report is None or report.uncertainty is None
        else report.uncertainty.heading_sigma_deg,
    )  # fmt: skip
    if calibration.frame == "vehicle":
        outcome.heading_mounted_deg = outcome.heading_deg
        outcome.alignment_deg = alignment_error_deg(polar_rotation(calibration.matrix), simulation)
    else:
        outcome.heading_mounted_deg = heading_error_deg(corrected @ simulation.mounting.T, simulation)
    return outcome


KEPT_DETAILS = ("lag_s", "chosen", "mapping", "reason")


def run_case(case: VehicleCase, fitters: Mapping[str, Fitter], root_seed: int) -> dict[str, list[VehicleOutcome]]:
    """Every fitter on every trial of ``case`` (the same recording for all); outcomes by column name.

    ``align`` (when magfit has it) runs on the samples corrected by the true magnitude-only calibration, by
    the trial's ``auto`` fit and by the magnitude-only part of its ``gyro`` fit (:data:`ALIGN_TRUE`,
    :data:`ALIGN_AUTO`, :data:`ALIGN_GYRO`; the last where gyro ran).
    """
    outcomes: dict[str, list[VehicleOutcome]] = {name: [] for name in fitters}
    aligning = alignment_available()
    if aligning:
        outcomes[ALIGN_TRUE], outcomes[ALIGN_AUTO], outcomes[ALIGN_GYRO] = [], [], []
    for trial in range(case.trials):
        simulation = case.simulate(root_seed, trial)
        fitted: dict[str, magfit.Calibration] = {}
        for name, fitter in fitters.items():
            if name.startswith("magyc.") and name.removeprefix("magyc.") not in case.magyc:
                continue
            if name == GYRO and not case.gyro:
                continue
            start = time.perf_counter()
            try:
                calibration = fitter(simulation)
            except Exception as error:  # a failing method is a result, recorded with its reason
                outcome = VehicleOutcome(error=failure_message(error))
                calibration = None
            else:
                outcome = score(calibration, simulation)
                fitted[name] = calibration
                outcome.details = kept_details(calibration, KEPT_DETAILS) or None
            outcome.seconds = time.perf_counter() - start
            method = METHOD_OF.get(name, name)
            if method in magfit.METHODS:
                outcome.verdict, outcome.verdict_reason = verdict_of(
                    calibration, outcome.error or "" if method in NOT_FORCED else ""
                )
            outcomes[name].append(outcome)
        if aligning:
            outcomes[ALIGN_TRUE].append(_align_outcome(simulation, simulation.truth_sensor))
            outcomes[ALIGN_AUTO].append(_align_outcome(simulation, fitted.get("auto")))
            kinematic = fitted.get(GYRO)
            if kinematic is not None and kinematic.gyro is not None and kinematic.gyro.sensor_matrix is not None:
                sensor_part = magfit.Calibration(
                    "gyro (magnitude-only part)", kinematic.offset,
                    np.asarray(kinematic.gyro.sensor_matrix, dtype=np.float64), kinematic.field_strength,
                )  # fmt: skip
                outcomes[ALIGN_GYRO].append(_align_outcome(simulation, sensor_part))
    return {name: values for name, values in outcomes.items() if values}


def _align_outcome(simulation: VehicleSimulation, calibration: magfit.Calibration | None) -> VehicleOutcome:
    if calibration is None:
        return VehicleOutcome(error="auto gave no calibration to align (refused or not run)")
    start = time.perf_counter()
    try:
        rotation = fit_alignment(simulation, calibration)
    except Exception as error:
        return VehicleOutcome(error=failure_message(error), seconds=time.perf_counter() - start)
    corrected = calibration.apply(simulation.clean) @ rotation.T
    return VehicleOutcome(
        heading_deg=heading_error_deg(corrected, simulation),
        heading_mounted_deg=heading_error_deg(corrected, simulation),
        alignment_deg=alignment_error_deg(rotation, simulation),
        offset_error=float(np.linalg.norm(calibration.offset - simulation.hard_iron) / simulation.truth.field_strength),
        frame="vehicle",
        seconds=time.perf_counter() - start,
    )


# ====================================================================== aggregation and targets


@dataclass
class VehicleSummary:
    """One cell: a method on a case, RMS over its trials."""

    trials: int
    failed: int
    heading_deg: float | None
    heading_mounted_deg: float | None
    alignment_deg: float | None
    offset_error: float | None
    seconds: float
    first_error: str | None = None
    verdicts: dict[str, int] = field(default_factory=dict)
    first_refusal: str | None = None


def _rms(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.sqrt(np.mean(np.square(kept)))) if kept else None


def summarise(outcomes: Sequence[VehicleOutcome]) -> VehicleSummary:
    ok = [o for o in outcomes if o.error is None]
    verdicts: dict[str, int] = {}
    for outcome in outcomes:
        if outcome.verdict is not None:
            verdicts[outcome.verdict] = verdicts.get(outcome.verdict, 0) + 1
    return VehicleSummary(
        trials=len(outcomes),
        failed=len(outcomes) - len(ok),
        heading_deg=_rms([o.heading_deg for o in ok]),
        heading_mounted_deg=_rms([o.heading_mounted_deg for o in ok]),
        alignment_deg=_rms([o.alignment_deg for o in ok]),
        offset_error=_rms([o.offset_error for o in ok]),
        seconds=float(np.mean([o.seconds or 0.0 for o in outcomes])),
        first_error=next((o.error for o in outcomes if o.error is not None), None),
        verdicts=verdicts,
        first_refusal=next((o.verdict_reason for o in outcomes if o.verdict == "refused"), None),
    )


@dataclass(frozen=True)
class _Heading:
    heading_deg: float | None


def _paired(outcomes: Sequence[VehicleOutcome], mounted: bool = False) -> list[_Heading]:
    """The heading errors (as given or with the true mounting) for the paired ratio (same trials, same samples)."""
    return [
        _Heading((o.heading_mounted_deg if mounted else o.heading_deg) if o.error is None else None) for o in outcomes
    ]


def _complete(outcomes: Sequence[VehicleOutcome] | None) -> bool:
    return bool(outcomes) and all(o.error is None for o in outcomes or ())


def best_magnitude_only(per_case: Mapping[str, Sequence[VehicleOutcome]], mounted: bool = True) -> str | None:
    """The magnitude-only method with the smallest RMS heading error (with the true mounting applied, or as
    given) among those that fitted every trial."""
    candidates = {
        name: getattr(summarise(per_case[name]), "heading_mounted_deg" if mounted else "heading_deg")
        for name in MAGNITUDE_METHODS
        if _complete(per_case.get(name))
    }
    scored = {name: value for name, value in candidates.items() if value is not None}
    return min(scored, key=lambda name: scored[name]) if scored else None


def _ratio_text(ratio: Ratio | None) -> str:
    return "—" if ratio is None else str(ratio)


def check_targets(
    cases: Sequence[VehicleCase], results: Mapping[str, Mapping[str, Sequence[VehicleOutcome]]]
) -> list[Target]:
    """The vehicle targets, PASS/FAIL/NOT RUN, with the numbers behind each."""
    targets: list[Target] = []
    restricted = [case for case in cases if case.motion != "tumble"]

    # 1. vector at most 0.5x the best magnitude-only method: as the magnitude-only fit gives it (the mounting
    #    unknown to it), and with the true mounting handed to it (the strict comparison).
    for mounted in (False, True):
        items: list[str] = []
        ok, ran = True, False
        for case in restricted:
            per_case = results[case.name]
            best = best_magnitude_only(per_case, mounted)
            if VECTOR not in per_case or best is None:
                items.append(f"{case.name}: " + ("vector not in this checkout" if VECTOR not in per_case
                                                  else "no magnitude-only method fitted every trial"))  # fmt: skip
                ok = ok and VECTOR in per_case  # no magnitude-only rival: nothing to beat
                continue
            ran = True
            ratio = paired_ratio(_paired(per_case[VECTOR]), _paired(per_case[best], mounted=mounted))
            failed = sum(o.error is not None for o in per_case[VECTOR])
            passed = ratio is not None and ratio.value <= 0.5 and failed == 0
            ok = ok and passed
            items.append(f"{case.name}: vector / {best} = {_ratio_text(ratio)}"
                         + (f", vector failed {failed} trials" if failed else "")
                         + f" {pass_fail(passed)}")  # fmt: skip
        how = "with the TRUE mounting applied to it" if mounted else "as it gives it (its axes taken as the vehicle's)"
        status = pass_fail(ok) if ran else "NOT RUN"
        targets.append(Target(f"vector ≤ 0.5 × the best magnitude-only method, {how}", status,
                              f"{len(restricted)} restricted cases", items))  # fmt: skip

    # 2. alignment within 0.5° of the truth at 1° of attitude noise.
    vector_label = "vector's rotation" + (" (with the accelerometer)" if _takes_accel(VECTOR) else "")
    gyro_label = "gyro's rotation" + (" (with the accelerometer)" if _takes_accel(GYRO) else "")
    aligners = ((VECTOR, vector_label), (GYRO, gyro_label), (ALIGN_TRUE, "align() on the truly calibrated field"),
                (ALIGN_AUTO, "align() after auto"),
                (ALIGN_GYRO, "align() after gyro's magnitude-only part (magfit align with a gyro)"))  # fmt: skip
    for name, label in aligners:
        items, ok, ran = [], True, False
        for case in cases:
            if case.attitude_noise_deg != 1.0:
                continue
            outcomes = results[case.name].get(name)
            if not outcomes:
                known = METHOD_OF.get(name, name) in magfit.METHODS or (name != VECTOR and name != GYRO
                                                                         and alignment_available())  # fmt: skip
                items.append(f"{case.name}: {name} " + ("not run on this case" if known else "not in this checkout"))
                continue
            ran = True
            summary = summarise(outcomes)
            passed = summary.failed == 0 and summary.alignment_deg is not None and summary.alignment_deg <= 0.5
            ok = ok and passed
            shown = "—" if summary.alignment_deg is None else f"{summary.alignment_deg:.3f}°"
            items.append(f"{case.name}: {shown} RMS" + (f", failed {summary.failed}" if summary.failed else "")
                         + f" {pass_fail(passed)}")  # fmt: skip
        targets.append(Target(f"alignment ({label}) within 0.5° of the true mounting at 1° of attitude noise",
                              pass_fail(ok) if ran else "NOT RUN", "RMS over trials", items))  # fmt: skip

    # 3. gyro-aided within 1.2x of vector where both apply; better than MAGYC's methods.
    gyro = GYRO if any(GYRO in per_case for per_case in results.values()) else None
    items, ok, ran = [], True, False
    magyc_items, magyc_ok, magyc_ran = [], True, False
    for case in cases:
        per_case = results[case.name]
        if gyro is None or gyro not in per_case:  # not run on this case (see VehicleCase.gyro)
            continue
        if VECTOR in per_case and _complete(per_case[VECTOR]):
            ran = True
            ratio = paired_ratio(_paired(per_case[gyro]), _paired(per_case[VECTOR]))
            failed = sum(o.error is not None for o in per_case[gyro])
            passed = ratio is not None and ratio.value <= 1.2 and failed == 0
            ok = ok and passed
            items.append(f"{case.name}: {gyro} / vector = {_ratio_text(ratio)}"
                         + (f", {gyro} failed {failed} trials" if failed else "")
                         + f" {pass_fail(passed)}")  # fmt: skip
        peers = [name for name in per_case if name.startswith("magyc.") and _complete(per_case[name])]
        if peers:
            magyc_ran = True
            best = min(peers, key=lambda name: summarise(per_case[name]).heading_deg or np.inf)
            ratio = paired_ratio(_paired(per_case[gyro], mounted=True), _paired(per_case[best]))
            passed = ratio is not None and ratio.value < 1.0 and _complete(per_case[gyro])
            magyc_ok = magyc_ok and passed
            magyc_items.append(f"{case.name}: {gyro} (true mounting if sensor frame) / {best} = "
                               f"{_ratio_text(ratio)} {pass_fail(passed)}")  # fmt: skip
    targets.append(Target("gyro-aided ≤ 1.2 × vector where both apply", pass_fail(ok) if ran else "NOT RUN",
                          "gyro-aided method: " + (gyro or "not in this checkout"), items))  # fmt: skip
    targets.append(Target("gyro-aided more accurate than the best of MAGYC's methods that fitted every trial",
                          pass_fail(magyc_ok) if magyc_ran and gyro else "NOT RUN",
                          "where MAGYC ran" if magyc_ran else "MAGYC not run", magyc_items))  # fmt: skip
    targets.append(_auto_covered(restricted, results))
    return targets


def _auto_covered(
    cases: Sequence[VehicleCase], results: Mapping[str, Mapping[str, Sequence[VehicleOutcome]]]
) -> Target:
    """Where ``auto`` answers, its stated heading one-sigma covers its heading error with the true mounting.

    The one-sigma is stated for level attitude over every heading; the error is over the attitudes recorded
    (the mounting the fit cannot know handed to it): the best a user who knows the mounting gets. A refusal
    states nothing and is counted beside, not against it (refusing where no bound is useful is the promise).
    """
    items, covered, answered = [], 0, 0
    for case in cases:
        outcomes = results[case.name].get("auto")
        if not outcomes:
            continue
        fitted = [o for o in outcomes if o.error is None and o.heading_mounted_deg is not None]
        pairs = [(o.heading_mounted_deg or 0.0, o.stated_heading_deg or 0.0) for o in fitted]
        inside = sum(1 for error, stated in pairs if error <= stated)
        worst = max((error / stated for error, stated in pairs if stated > 0.0), default=None)
        answered += len(fitted)
        covered += inside
        items.append(f"{case.name}: covered {inside}/{len(fitted)} answered"
                     + (f", worst error / stated {worst:.2f}" if worst is not None else "")
                     + (f"; refused {len(outcomes) - len(fitted)}/{len(outcomes)}" if len(fitted) < len(outcomes)
                        else ""))  # fmt: skip
    status = pass_fail(covered >= 0.9 * answered) if answered else "NOT RUN"
    return Target("auto's stated heading one-sigma ≥ its heading error (true mounting) on ≥ 90 % of the trials it "
                  "answers", status, f"covered on {covered}/{answered} answered trials", items)  # fmt: skip


# ====================================================================== the report


def run(
    cases: Sequence[VehicleCase],
    *,
    methods: Sequence[str] | None = None,
    peers: bool = True,
    seed: int = 20261124,
    command: str = "",
    progress: Callable[[str], None] | None = None,
    broad_data: Path | None = None,
) -> dict[str, Any]:
    """Run the vehicle scenarios and return the report (rendered by :func:`render_markdown`).

    ``broad_data``: the folder of BROAD's ``data_mat`` files (``git clone https://github.com/dlaidig/broad``);
    the trials of :data:`BROAD_TRIALS` found there are scored by :func:`run_real`.
    """
    start = time.perf_counter()
    found_versions = versions(peers)
    fitters = method_table(methods, peers)
    results: dict[str, dict[str, list[VehicleOutcome]]] = {}
    for case in cases:
        case_start = time.perf_counter()
        results[case.name] = run_case(case, fitters, seed)
        if progress:
            progress(f"{case.name}: {case.trials} trials in {time.perf_counter() - case_start:.1f} s")
    real: dict[str, Any] = {}
    if broad_data is not None:
        for trial in BROAD_TRIALS:
            path = broad_data / f"{trial}.mat"
            if path.is_file():
                real[trial] = run_real(read_broad(path), methods)
                if progress:
                    progress(f"BROAD {trial}: {real[trial]['test_samples']} samples scored")
    summaries = {name: {m: summarise(o) for m, o in per_case.items()} for name, per_case in results.items()}
    columns = list(dict.fromkeys(m for per_case in results.values() for m in per_case))
    return {
        "command": command,
        "date": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "runtime_s": time.perf_counter() - start,
        "seed": seed,
        "versions": found_versions,
        "methods": columns,
        "cases": [asdict(case) for case in cases],
        "summaries": summaries,
        "outcomes": results,
        "targets": check_targets(cases, results) + ([real_target(real)] if real else []),
        "real": real,
        "broad_data": None if broad_data is None else str(broad_data),
    }


def real_target(real: Mapping[str, Any]) -> Target:
    """The real-log target: vector's heading error within 1.3 × the plain regression's, per recording."""
    items, ok, ran = [], True, False
    for trial, result in real.items():
        rows = result["methods"]
        vector, baseline = rows.get(VECTOR, {}), rows.get(REGRESSION, {})
        if "heading_deg" not in vector or "heading_deg" not in baseline:
            items.append(f"{trial}: vector {vector.get('error', 'not in this checkout')}")
            ok = ok and VECTOR not in magfit.METHODS
            continue
        ran = True
        ratio = vector["heading_deg"] / baseline["heading_deg"]
        passed = ratio <= 1.3
        ok = ok and passed
        items.append(f"{trial}: vector {vector['heading_deg']:.3g}° / regression {baseline['heading_deg']:.3g}° = "
                     f"{ratio:.3f} {pass_fail(passed)}")  # fmt: skip
    return Target("real recordings with an independent attitude (BROAD): vector ≤ 1.3 × the plain regression",
                  pass_fail(ok) if ran else "NOT RUN", f"{len(real)} recordings", items)  # fmt: skip


def _deg(value: float | None) -> str:
    return "—" if value is None else f"{value:.3g}"


def _cell(summary: VehicleSummary | None, text: str, notes: dict[str, int]) -> str:
    if summary is None:
        return "not run"
    if summary.failed == summary.trials:
        return f"fails [{note(notes, summary.first_error or 'failed')}]"
    if summary.failed:
        text += f" ({summary.failed}/{summary.trials} failed [{note(notes, summary.first_error or 'failed')}])"
    return text


def _table(title: str, report: Mapping[str, Any], cell: Callable[[VehicleSummary], str | None],
           notes: dict[str, int]) -> list[str]:  # fmt: skip
    columns = [m for m in report["methods"] if any(
        cell(s[m]) is not None for s in report["summaries"].values() if m in s)]  # fmt: skip
    lines = [f"### {title}", "", "| case | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for case in report["cases"]:
        per_case = report["summaries"][case["name"]]
        cells = []
        for method in columns:
            summary = per_case.get(method)
            text = cell(summary) if summary is not None else None
            cells.append(_cell(summary, text or "—", notes) if summary is not None else "not run")
        lines.append(f"| {case['name']} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def render_markdown(report: Mapping[str, Any]) -> str:
    """The results file: header, scenarios, tables, targets, footnotes."""
    notes: dict[str, int] = {}
    lines = [
        "# Vehicle-aided calibration accuracy",
        "",
        f"`{report['command']}` — {report['date']} UTC, {report['runtime_s']:.0f} s, seed {report['seed']}.",
        "",
        "Versions: " + ", ".join(f"{k} {v}" for k, v in report["versions"].items()) + ".",
        "",
        "Metrics and scenarios: `benchmarks/accuracy_vehicle.py` (module docstring) and `benchmarks/README.md`.",
        "",
        "## Scenarios",
        "",
        "| case | motion | samples | rate | attitude error | lag | mounting | trials |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for case in report["cases"]:
        low, high = case["mounting_deg"]
        mounting = "aligned" if high == 0 else f"{low:g}-{high:g}° about a random axis"
        motion = "every attitude" if case["motion"] == "tumble" else f"tilt ±{case['max_tilt_deg']:g}°"
        lines.append(f"| {case['name']} | {case['motion']} ({motion}) | {case['n']} | "
                     f"{case['rate_hz']:g} Hz | {case['attitude_noise_deg']:g}° | {case['lag_s']:g} s | {mounting} | "
                     f"{case['trials']} |")  # fmt: skip
    lines += ["", "## Results", ""]
    lines += _table("Heading error, degrees (RMS over the recording and the trials), as the calibration gives it",
                    report, lambda s: _deg(s.heading_deg), notes)  # fmt: skip
    lines += _table("Heading error with the TRUE mounting applied to sensor-frame calibrations, degrees", report,
                    lambda s: _deg(s.heading_mounted_deg), notes)  # fmt: skip
    lines += _table("Alignment error, degrees (fitted vs true magnetometer-to-vehicle rotation)", report,
                    lambda s: None if s.alignment_deg is None else _deg(s.alignment_deg), notes)  # fmt: skip
    lines += _table("Offset error |V − V_true| / B, %", report,
                    lambda s: None if s.offset_error is None else f"{100 * s.offset_error:.3g}", notes)  # fmt: skip
    lines += _table("magfit's verdict over the trials (supported / weak / refused)", report,
                    lambda s: None if not s.verdicts else "/".join(
                        str(s.verdicts.get(v, 0)) for v in ("supported", "weak", "refused")), notes)  # fmt: skip
    lines += _table("Seconds per fit", report, lambda s: f"{s.seconds:.2f}", notes)
    if report.get("real"):
        lines += _real_section(report["real"], notes)
    lines += ["## Targets", ""]
    for target in report["targets"]:
        lines.append(f"- **{target.status}** {target.name} ({target.detail})")
        lines += [f"  - {item}" for item in target.items]
    if notes:
        lines += ["", "## Notes", ""]
        lines += [f"{number}. {message}" for message, number in notes.items()]
    return "\n".join(lines) + "\n"


def _real_section(real: Mapping[str, Any], notes: dict[str, int]) -> list[str]:
    columns = list(dict.fromkeys(name for result in real.values() for name in result["methods"]))
    lines = [
        "### Real recordings with an independent attitude: BROAD (optical motion capture)",
        "",
        "Heading error, degrees: RMS over 0.25 s windows of the held-out stretches (alternate 10 s; the fits see the "
        "others, every 4th sample), the field of each window turned into ENU by the optical attitude. "
        "In brackets: the rotation of a vehicle-frame matrix (polar factor), degrees.",
        "",
        "| recording | samples (fit / scored) | " + " | ".join(columns) + " |",
        "|---" * (len(columns) + 2) + "|",
    ]
    for trial, result in real.items():
        cells = []
        for name in columns:
            row = result["methods"].get(name)
            if row is None:
                cells.append("not run")
            elif "error" in row:
                cells.append(f"fails [{note(notes, row['error'])}]")
            else:
                rotation = f" ({row['rotation_deg']:.2f}°)" if "rotation_deg" in row else ""
                verdict = f" {row['verdict']}" if row.get("verdict") and row["verdict"] != "supported" else ""
                cells.append(f"{row['heading_deg']:.3g}{rotation}{verdict}")
        lines.append(f"| {trial} | {result['fit_samples']} / {result['test_samples']} | " + " | ".join(cells) + " |")
    return [*lines, ""]


# ====================================================================== a real recording with an independent attitude

#: BROAD (Laidig et al., "BROAD - a benchmark for robust inertial orientation estimation", Data 6(7), 2021;
#: github.com/dlaidig/broad, CC BY 4.0): an IMU (myon aktos-t: magnetometer in µT, gyro, accelerometer)
#: moved by hand inside an optical motion-capture system (Optitrack), whose orientation ``opt_quat``
#: (scalar first, body → ENU, synchronised and aligned to the IMU's axes by the authors) is independent of
#: the magnetometer but for one constant: the heading of the reference frame (its east component of the
#: field is 0: the authors turned it to magnetic north). The undisturbed trials whose files are complete.
BROAD_TRIALS = (
    "02_undisturbed_slow_rotation_B",
    "03_undisturbed_slow_rotation_C",
    "05_undisturbed_slow_rotation_with_breaks_B",
    "07_undisturbed_fast_rotation_B",
    "09_undisturbed_fast_rotation_with_breaks_B",
    "21_undisturbed_fast_combined",
)
#: The fits take every 4th sample (286 Hz → 71 Hz): they need no more, and the vector fit's cost grows with N.
BROAD_STRIDE = 4
#: The heading is scored on the mean world-frame field of each 0.25 s (71 samples): the magnetometer's
#: noise (0.3-0.7 µT per axis against a horizontal field of 15 µT: 2-3° per sample) averages out, the
#: calibration's error, which changes with the attitude, hardly does.
BROAD_WINDOW_S = 0.25
#: Fitting and evaluating on alternate stretches of this length: each calibration is scored on samples
#: it never saw, over the same kinds of motion.
BROAD_BLOCK_S = 10.0


@dataclass(frozen=True)
class AttitudeRecording:
    """A real recording with an attitude reference: samples (N, 3), attitude body → ENU (N, 3, 3), time (N,)."""

    name: str
    time_s: NDArray[np.float64]
    samples: NDArray[np.float64]
    attitude: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]


def read_broad(path: Any) -> AttitudeRecording:
    """One BROAD trial (``data_mat/NN_name.mat``): the samples where the optical reference saw the IMU."""
    from scipy.io import loadmat

    data = loadmat(str(path))
    quaternion = np.asarray(data["opt_quat"], dtype=np.float64)
    seen = np.all(np.isfinite(quaternion), axis=1)  # NaN where the markers were occluded
    rate = float(np.asarray(data["sampling_rate"]).ravel()[0])
    keep = np.flatnonzero(seen)
    attitude = Rotation.from_quat(quaternion[keep][:, [1, 2, 3, 0]]).as_matrix()  # scalar-first in the file
    return AttitudeRecording(
        name=str(getattr(path, "stem", path)),
        time_s=keep / rate,
        samples=np.asarray(data["imu_mag"], dtype=np.float64)[keep],
        attitude=attitude,
        gyro=np.asarray(data["imu_gyr"], dtype=np.float64)[keep],
        accel=np.asarray(data["imu_acc"], dtype=np.float64)[keep],
    )


def _enu_heading_error_deg(
    body: NDArray[np.float64], attitude: NDArray[np.float64], field_enu: NDArray[np.float64], window: NDArray[np.int_]
) -> float:
    """RMS over the windows of the heading error of the mean world-frame field of each window."""
    world = np.einsum("kij,kj->ki", attitude, body)
    _, index = np.unique(window, return_inverse=True)
    sums = np.zeros((index.max() + 1, 3))
    np.add.at(sums, index, world)
    truth = np.arctan2(field_enu[0], field_enu[1])  # atan2(east, north)
    return float(np.sqrt(np.mean(_wrapped_deg(np.arctan2(sums[:, 0], sums[:, 1]) - truth) ** 2)))


def run_real(recording: AttitudeRecording, methods: Sequence[str] | None = None) -> dict[str, Any]:
    """Fit on alternate stretches of ``recording``, score headings on the others with the optical attitude.

    The Earth's field in the reference frame is not given: it is the mean, over the fitting stretches, of
    the field that the forced ``ml`` fit corrects, turned into ENU by the optical attitude (three numbers
    taken from the magnetometer; the attitude stays the reference's). Every method that needs a reference
    gets ``attitudeᵀ f`` from it; the plain regression is the yardstick of the real-log target (vector ≤ 1.3 × it).
    """
    elapsed = recording.time_s - recording.time_s[0]
    block = np.floor(elapsed / BROAD_BLOCK_S).astype(int)
    fit_rows = np.flatnonzero(block % 2 == 0)[::BROAD_STRIDE]
    test_rows = np.flatnonzero(block % 2 == 1)
    window = np.floor(elapsed[test_rows] / BROAD_WINDOW_S).astype(int)
    samples, attitude = recording.samples[fit_rows], recording.attitude[fit_rows]
    magnitude = magfit.fit(samples, method="ml", allow_undetermined=True)
    corrected = magnitude.apply(samples)
    field_enu = np.mean(np.einsum("kij,kj->ki", attitude, corrected), axis=0)
    field_enu *= magnitude.field_strength / np.linalg.norm(field_enu)
    reference = np.einsum("kji,j->ki", attitude, field_enu)  # attitudeᵀ f
    fitters: dict[str, Callable[[], magfit.Calibration]] = {
        "as logged": lambda: magfit.Calibration("identity", np.zeros(3), np.eye(3), magnitude.field_strength),
        "ml": lambda: magnitude,
        "auto": lambda: magfit.fit(samples, method="auto"),
        REGRESSION: lambda: plain_regression(samples, reference),
    }
    if VECTOR in magfit.METHODS:
        streams = {"reference": reference, "time_s": recording.time_s[fit_rows], "gyro": recording.gyro[fit_rows],
                   "accel": recording.accel[fit_rows]}  # fmt: skip
        taken = {key: value for key, value in streams.items() if key in magfit.METHODS[VECTOR].options}
        fitters[VECTOR] = lambda: magfit.fit(samples, method=VECTOR, allow_undetermined=True, **taken)
        if _takes_accel(VECTOR):
            alone = {key: value for key, value in taken.items() if key not in ("accel", "gyro")}
            fitters[VECTOR_NO_ACCEL] = lambda: magfit.fit(samples, method=VECTOR, allow_undetermined=True, **alone)
    rows: dict[str, dict[str, Any]] = {}
    for name, fitter in fitters.items():
        if methods is not None and not {name, METHOD_OF.get(name)} & {*methods, "as logged", REGRESSION}:
            continue
        start = time.perf_counter()
        try:
            calibration = fitter()
        except Exception as error:
            rows[name] = {"error": failure_message(error)}
            continue
        body = calibration.apply(recording.samples[test_rows])
        row: dict[str, Any] = {
            "heading_deg": _enu_heading_error_deg(body, recording.attitude[test_rows], field_enu, window),
            "frame": calibration.frame,
            "seconds": time.perf_counter() - start,
        }
        if calibration.frame == "vehicle":
            row["rotation_deg"] = rotation_angle_deg(polar_rotation(calibration.matrix))
        if calibration.support is not None:
            row["verdict"] = calibration.support.verdict
        rows[name] = row
    return {
        "samples": len(recording.samples),
        "fit_samples": len(fit_rows),
        "test_samples": len(test_rows),
        "duration_s": float(recording.time_s[-1] - recording.time_s[0]),
        "field_enu": field_enu.tolist(),
        "methods": rows,
    }
