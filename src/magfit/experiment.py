"""The paper's experiment (section V), re-run on simulated sensors.

The paper calibrates two sensors (an MPU-9250 in raw counts, an SBG Ellipse 2A in normalised units) in
three situations (no perturbation, a 0.8 kg piece of steel fixed to the sensor, a smartphone attached)
with its three methods, and reports the mean and standard deviation of the distance of the calibrated
samples to the unit sphere, plus the fitted ellipsoid semi-axes and hard-iron offsets. Its recordings
are not public; :func:`magfit.scenario` rebuilds each situation from the ellipsoids the paper reports,
so :func:`run_experiment` reproduces the tables with a known truth beside every fit.

The published numbers are kept in :data:`PAPER_DISTANCES` so that a report can show them next to the
simulated ones, and :func:`findings` checks the paper's conclusions on a run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .compare import PAPER_METHODS, Comparison, compare
from .simulate import DISTURBANCES, SENSORS, Scenario, Simulation, scenario

__all__ = [
    "DEFAULT_SAMPLES",
    "DEFAULT_SEED",
    "DISTURBANCE_LABELS",
    "METHOD_LABELS",
    "PAPER_DISTANCES",
    "SENSOR_LABELS",
    "Case",
    "Experiment",
    "Finding",
    "findings",
    "run_experiment",
]

#: Samples simulated per case. The paper does not give its count; 5000 makes the std stable to ~1%.
DEFAULT_SAMPLES = 5000
#: Seed of the default run, so that ``magfit demo`` prints the same tables every time.
DEFAULT_SEED = 1

SENSOR_LABELS = {"mpu9250": "MPU-9250", "ellipse2a": "SBG Ellipse 2A"}
DISTURBANCE_LABELS = {"none": "No perturbation", "steel": "0.8 kg piece of steel", "smartphone": "Smartphone"}
METHOD_LABELS = {
    "ellipsoid": "Soft and hard-iron calibration",
    "sphere": "Hard-iron only calibration",
    "minmax": "Pseudo-calibration",
}

#: The paper's section V tables: (disturbance, method, sensor) -> (mean, std) of the sphere distances,
#: measured on the authors' real recordings.
PAPER_DISTANCES: dict[tuple[str, str, str], tuple[float, float]] = {
    ("none", "ellipsoid", "mpu9250"): (0.0028, 0.0236),
    ("none", "ellipsoid", "ellipse2a"): (0.0003, 0.0108),
    ("none", "sphere", "mpu9250"): (0.0004, 0.0296),
    ("none", "sphere", "ellipse2a"): (0.0002, 0.0183),
    ("none", "minmax", "mpu9250"): (0.0266, 0.029),
    ("none", "minmax", "ellipse2a"): (0.0049, 0.042),
    ("steel", "ellipsoid", "mpu9250"): (0.0088, 0.0462),
    ("steel", "ellipsoid", "ellipse2a"): (0.0012, 0.0219),
    ("steel", "sphere", "mpu9250"): (0.0079, 0.1254),
    ("steel", "sphere", "ellipse2a"): (0.0251, 0.2228),
    ("steel", "minmax", "mpu9250"): (0.0469, 0.155),
    ("steel", "minmax", "ellipse2a"): (0.0381, 0.1226),
    ("smartphone", "ellipsoid", "mpu9250"): (0.0189, 0.0717),
    ("smartphone", "ellipsoid", "ellipse2a"): (0.0029, 0.0288),
    ("smartphone", "sphere", "mpu9250"): (0.0016, 0.0562),
    ("smartphone", "sphere", "ellipse2a"): (0.0006, 0.0344),
    ("smartphone", "minmax", "mpu9250"): (0.0431, 0.0575),
    ("smartphone", "minmax", "ellipse2a"): (0.0124, 0.0416),
}


@dataclass(frozen=True, eq=False)
class Case:
    """One cell of the experiment: a scenario, its simulated samples and the methods' results on them."""

    scenario: Scenario
    simulation: Simulation
    comparison: Comparison

    @property
    def sensor(self) -> str:
        return self.scenario.sensor

    @property
    def disturbance(self) -> str:
        return self.scenario.disturbance


@dataclass(frozen=True, eq=False)
class Experiment:
    """The whole experiment: every sensor x disturbance case, in the order of ``SENSORS`` x ``DISTURBANCES``.

    Attributes
    ----------
    n_samples : int
        Samples simulated per case.
    seed : int
        Seed of the run; the same seed gives the same samples and the same tables.
    methods : tuple of str
        The methods compared in every case.
    cases : tuple of Case
    """

    n_samples: int
    seed: int
    methods: tuple[str, ...]
    cases: tuple[Case, ...]

    def case(self, sensor: str, disturbance: str) -> Case:
        """The case of ``sensor`` and ``disturbance``."""
        for case in self.cases:
            if case.sensor == sensor and case.disturbance == disturbance:
                return case
        raise KeyError(f"no case {sensor}/{disturbance} in this experiment")


def run_experiment(
    n_samples: int = DEFAULT_SAMPLES,
    *,
    seed: int = DEFAULT_SEED,
    methods: tuple[str, ...] = PAPER_METHODS,
    sensors: tuple[str, ...] = SENSORS,
    disturbances: tuple[str, ...] = DISTURBANCES,
) -> Experiment:
    """Simulate every case of the paper's experiment and compare the methods on each.

    Parameters
    ----------
    n_samples : int
        Samples per case (a full tumble: every attitude equally likely, as the paper's "rotated in all
        the directions at least two times").
    seed : int
        Seed of the whole run; each case draws from its own stream spawned from it, so adding or
        removing a case does not change the samples of the others.
    methods : tuple of str
        Methods to compare; the paper's three by default.
    sensors, disturbances : tuple of str
        Subsets of ``magfit.SENSORS`` and ``magfit.DISTURBANCES``.

    Returns
    -------
    Experiment
    """
    cases = []
    for sensor in sensors:
        for disturbance in disturbances:
            situation = scenario(sensor, disturbance)
            # One independent stream per case, keyed by the case's position in the full experiment.
            key = (SENSORS.index(sensor), DISTURBANCES.index(disturbance))
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))
            simulation = situation.simulate(n_samples, seed=rng)
            cases.append(Case(situation, simulation, compare(simulation.samples, methods, allow_undetermined=True)))
    return Experiment(n_samples, seed, tuple(methods), tuple(cases))


@dataclass(frozen=True)
class Finding:
    """One of the paper's conclusions, checked on a run: what it says, whether it holds, the numbers."""

    statement: str
    holds: bool
    evidence: str


def _std(case: Case, method: str) -> float:
    evaluation = case.comparison[method].evaluation
    return float("nan") if evaluation is None else evaluation.std


def _mean(case: Case, method: str) -> float:
    evaluation = case.comparison[method].evaluation
    return float("nan") if evaluation is None else evaluation.mean


def findings(experiment: Experiment, *, soft_iron_factor: float = 3.0) -> list[Finding]:
    """Check the paper's conclusions (section V) on an experiment that ran its three methods.

    1. With the piece of steel (strong soft iron), the soft + hard iron fit's std is several times
       (``soft_iron_factor``) below both the hard-iron-only fit's and the pseudo-calibration's.
    2. Without soft iron to speak of (no perturbation, smartphone), the three methods' std stay within
       one order of magnitude of each other.
    3. In those cases the pseudo-calibration is the least accurate: its mean distance is the largest.

    Returns
    -------
    list of Finding
        One per conclusion and sensor present in the experiment.
    """
    missing = sorted(set(PAPER_METHODS) - set(experiment.methods))
    if missing:
        raise KeyError(f"findings() needs the paper's three methods; the experiment lacks {', '.join(missing)}")
    result = []
    disturbances = {case.disturbance for case in experiment.cases}
    sensors = [sensor for sensor in SENSORS if any(case.sensor == sensor for case in experiment.cases)]
    for sensor in sensors:
        label = SENSOR_LABELS[sensor]
        if "steel" in disturbances:
            case = experiment.case(sensor, "steel")
            ellipsoid, sphere, minmax = (_std(case, m) for m in PAPER_METHODS)
            ratio = min(sphere, minmax) / ellipsoid
            result.append(
                Finding(
                    f"{label}, steel: ellipsoid std {soft_iron_factor:g}x or more below sphere and minmax",
                    bool(ratio >= soft_iron_factor),
                    f"ellipsoid {ellipsoid:.4f}, sphere {sphere:.4f}, minmax {minmax:.4f} ({ratio:.1f}x)",
                ),
            )
        for disturbance in ("none", "smartphone"):
            if disturbance not in disturbances:
                continue
            case = experiment.case(sensor, disturbance)
            stds = [_std(case, m) for m in PAPER_METHODS]
            spread = max(stds) / min(stds)
            result.append(
                Finding(
                    f"{label}, {DISTURBANCE_LABELS[disturbance].lower()}: all std within 10x of each other",
                    bool(spread < 10.0),
                    ", ".join(f"{m} {s:.4f}" for m, s in zip(PAPER_METHODS, stds, strict=True)) + f" ({spread:.1f}x)",
                )
            )
            means = {m: abs(_mean(case, m)) for m in PAPER_METHODS}
            result.append(
                Finding(
                    f"{label}, {DISTURBANCE_LABELS[disturbance].lower()}: minmax has the largest |mean|",
                    bool(means["minmax"] > max(means["ellipsoid"], means["sphere"])),
                    ", ".join(f"{m} {means[m]:.4f}" for m in PAPER_METHODS),
                )
            )
    return result
