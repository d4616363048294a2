"""Accuracy benchmark: every magfit method and the peers a user would pick instead, side by side.

Run (from the checkout, in the benchmark's own environment made by ``benchmarks/setup_peers.sh``)::

    benchmarks/.peers-venv/bin/python benchmarks/accuracy.py

It simulates the paper's model (eq. 1), ``B_p = W R B (cos δ, 0, sin δ)ᵀ + V``, with a known truth, fits
every method to the same samples and scores the fits against the truth; then it fits the real recordings
in ``../shared/data/real`` and scores them on held-out samples. It writes ``benchmarks/results/accuracy.md``
(the tables and the targets, PASS/FAIL) and ``accuracy.json`` (every number), headed by the command
line and the versions. ``--smoke`` runs a tiny grid in seconds (what the test runs). ``--vehicle`` runs
the vehicle scenarios instead (attitude-aided, alignment and gyro-aided fits: ``accuracy_vehicle.py``),
into ``results/vehicle``.

Metrics (each per trial, then aggregated over the seeded trials of a case)
--------------------------------------------------------------------------
calibration heading error
    The fitted calibration applied to noise-free readings of the true distorted field
    (``Simulation.distort``) at level attitude (roll = pitch = 0) for 360 headings, 1° apart; the RMS
    over headings of the difference between the heading ``atan2(y, x)`` of the calibrated vector and of
    the truly calibrated vector ``sim.truth.apply``. Only ``A = matrixᵀ matrix`` is identifiable: a
    correct fit may differ from the truth by a rotation Q. Before comparing, the fitted output is
    turned by the rotation that best maps it onto the true calibrated field over *all* directions,
    ``Q = polar(M_true M_fit⁻¹)``: for calibrated vectors ``c = M_fit (x − V_fit)`` of a field uniform
    on the sphere, ``E|Q c − t|²`` is smallest for that Q (orthogonal Procrustes, eq. (P) below), and
    it does not depend on the test headings, the offset error or the scale. A correct fit scores 0; a
    constant heading rotation that no magnetometer-only calibration can observe is not counted, every
    other error is. Aggregated as the RMS over trials (comparable with the Cramér–Rao floor).
offset error
    ``|V_fit − V_true| / B`` (dimensionless; RMS over trials).
shape error
    ``‖Â − Â_true‖_F / ‖Â_true‖_F`` with ``Â = A / det(A)^(1/3)``, ``A = matrixᵀ matrix``: the soft-iron
    shape with scale removed (RMS over trials).
sphere distances
    The paper's section V metric, ``magfit.evaluate``: mean and std of ``|apply(x, normalized=True)| − 1``
    on the fitted samples and on held-out samples (10 000 fresh samples of the same simulation, same
    noise and attitudes, without spikes). Averaged over trials.
no calibration
    The heading error of the raw readings (offset 0, identity matrix), per trial: the yardstick. On the
    flight cases ``auto`` is held to it over the attitudes each trial flew (``flown_deg``, the aircraft
    benchmark's ``attitude_heading_error_deg``): at level the raw readings ignore the offset along the
    sensor's z axis, which leans into the heading once the aircraft banks. The level comparison is listed.
support verdict
    magfit's own judgement of each fit (``calibration.support``: supported, weak, refused). Every magfit
    method but ``auto`` is fitted with ``allow_undetermined=True``, so the numbers above are what the
    method gives even where the samples do not support it; the verdicts are counted beside them.
    ``auto`` is not forced: its refusal is its answer, a failure with its reason.
floor
    The Cramér–Rao bound of the geometric noise model (each sample a point of the true ellipsoid plus
    isotropic Gaussian noise; the points are nuisance parameters), propagated to the heading error by
    the delta method; see :func:`cramer_rao_heading_deg`.

(P): with ``t = M_true(x − V_true)`` uniform on the sphere and ``c = M_fit(x − V_fit)``,
``argmax_Q E tr(Q c tᵀ) = argmax_Q tr(Q M_fit M_true⁻¹) ∝`` the orthogonal polar factor of
``(M_fit M_true⁻¹)ᵀ``, i.e. ``polar(M_true M_fit⁻¹)`` (Schönemann 1966, orthogonal Procrustes).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from _common import (
    N_HEADINGS,
    Ratio,
    Target,
    heading_differences_deg,
    heading_error_deg,
    kept_details,
    level_readings,
    mild_distortion,
    paired_ratio,
    report_json,
    verdict_of,
    versions,
)
from _common import (
    best_rotation as best_rotation,  # (its tests read it here)
)
from _common import failure_message as _failure_message
from _common import note as _note
from _common import pass_fail as _status
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

import magfit

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_REAL_DATA = Path(os.environ.get("MAGFIT_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
HELDOUT_SAMPLES = 10_000
MAX_TILT_DEG = 20.0
SPIKE_FRACTION = 0.02
#: Spike magnitudes, as fractions of the field strength B: a random direction and a length uniform in
#: this range, added to 2 % of the samples (glitches of a bus read or a passing magnet).
SPIKE_RANGE = (0.2, 1.0)

# The generic sensor of the noise and N sweeps (B = 1, so noise is a fraction of the field): a moderate
# soft iron (semi-axes 1.25, 1.0, 0.8, turned 30° about (1, 2, 3)) and a hard iron of about the field.
_GENERIC_ROTATION = Rotation.from_rotvec(np.radians(30.0) * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)).as_matrix()
GENERIC_SOFT_IRON = _GENERIC_ROTATION @ np.diag([1.25, 1.0, 0.8]) @ _GENERIC_ROTATION.T
GENERIC_HARD_IRON = np.array([0.5, -0.3, 0.8])
GENERIC_INCLINATION_DEG = 64.0

# ====================================================================== scenarios


@dataclass(frozen=True)
class Case:
    """One simulated scenario of the grid, run for ``trials`` seeded trials.

    Attributes
    ----------
    name : str
        Row label of the tables.
    n : int
        Samples per fit.
    noise : float
        Noise standard deviation per axis as a fraction of the field strength B (for a paper scenario,
        ``None`` keeps the sensor's own noise).
    orientations : {"uniform", "restricted", "flight"}
        Full tumble; full yaw with roll and pitch uniform within ±``max_tilt_deg``; or a time-ordered
        recording of level flight with banked turns, roll and pitch within ±``max_tilt_deg``.
    spikes : bool
        Whether 2 % of the samples carry a spike (see ``SPIKE_RANGE``).
    paper : tuple of (sensor, disturbance) or None
        A paper scenario (``magfit.scenario``) instead of the generic sensor.
    trials : int
        Number of seeded trials.
    seed_key : str
        Cases with the same key draw the same samples trial by trial (the spike case reuses the samples
        of its spike-free twin, spikes added).
    heldout : int
        Number of held-out samples per trial.
    max_tilt_deg : float
        Roll and pitch limit of the restricted and flight attitudes, degrees.
    field_drift : float
        Relative amplitude of a slow drift of the field strength along the recording (``magfit.simulate``'s
        ``field_drift``): model error that no calibration holds.
    sensor : {"generic", "mild", "aircraft"}
        ``"generic"``: the fixed sensor of the sweeps (``GENERIC_SOFT_IRON``, ``GENERIC_HARD_IRON``).
        ``"mild"``: a new sensor each trial (:func:`mild_distortion`), the same for its held-out samples.
        ``"aircraft"``: a new sensor in a new aircraft each trial (:func:`aircraft_distortion`): its
        permanent and induced fields as V and W, its eddy-current field as ``eddy_current`` (eq. 1e of
        :mod:`magfit.simulate`), which follows the manoeuvres and no calibration holds.
    """

    name: str
    n: int
    noise: float | None
    orientations: str = "uniform"
    spikes: bool = False
    paper: tuple[str, str] | None = None
    trials: int = 10
    seed_key: str = ""
    heldout: int = HELDOUT_SAMPLES
    max_tilt_deg: float = MAX_TILT_DEG
    field_drift: float = 0.0
    sensor: str = "generic"

    @property
    def full_tumble(self) -> bool:
        """Uniform attitudes (every case but the restricted-attitude one)."""
        return self.orientations == "uniform"

    @property
    def gaussian(self) -> bool:
        """Full tumble with Gaussian noise only: the cases the Cramér–Rao floor applies to."""
        return self.full_tumble and not self.spikes and not self.field_drift

    @property
    def has_floor(self) -> bool:
        """Whether the Cramér–Rao floor is defined: one fixed sensor and no drift (model error is no noise)."""
        return self.sensor == "generic" and not self.field_drift

    def _scenario(self) -> magfit.Scenario | None:
        return None if self.paper is None else magfit.scenario(*self.paper)

    @property
    def field_strength(self) -> float:
        scenario = self._scenario()
        return 1.0 if scenario is None else scenario.field_strength

    @property
    def noise_std(self) -> float:
        """Noise standard deviation per axis, input units."""
        scenario = self._scenario()
        if scenario is None:
            return float(self.noise or 0.0)
        return scenario.noise if self.noise is None else self.noise * scenario.field_strength

    def simulate(
        self,
        n: int,
        rng: np.random.Generator,
        distortion: tuple[NDArray[np.float64], ...] | None = None,
    ) -> magfit.Simulation:
        """``n`` samples of this case's sensor (no spikes); ``distortion`` = (W, V) replaces the generic one,
        (W, V, E) adds the eddy-current field E (seconds, eq. 1e of :mod:`magfit.simulate`)."""
        scenario = self._scenario()
        if scenario is not None:
            return scenario.simulate(
                n,
                seed=rng,
                orientations=self.orientations,
                max_tilt_deg=self.max_tilt_deg,
                noise=None if self.noise is None else self.noise * scenario.field_strength,
            )
        soft_iron, hard_iron, *eddy = distortion or (GENERIC_SOFT_IRON, GENERIC_HARD_IRON)
        return magfit.simulate(
            n,
            soft_iron=soft_iron,
            hard_iron=hard_iron,
            field_strength=1.0,
            inclination_deg=GENERIC_INCLINATION_DEG,
            noise=self.noise_std,
            orientations=self.orientations,
            max_tilt_deg=self.max_tilt_deg,
            field_drift=self.field_drift,
            eddy_current=eddy[0] if eddy else None,
            seed=rng,
        )

    def trial_data(
        self, root_seed: int, trial: int
    ) -> tuple[magfit.Simulation, NDArray[np.float64], NDArray[np.float64]]:
        """The simulation, the samples to fit (spikes added if any) and held-out samples of one trial."""
        key = zlib.crc32((self.seed_key or self.name).encode())
        # The first three streams are those of the cases without a random sensor (spawn is prefix-stable).
        streams = np.random.SeedSequence([root_seed, key, trial]).spawn(4)
        draw = {"mild": mild_distortion, "aircraft": aircraft_distortion}.get(self.sensor)
        distortion = draw(np.random.default_rng(streams[3])) if draw is not None else None
        simulation = self.simulate(self.n, np.random.default_rng(streams[0]), distortion)
        heldout = self.simulate(self.heldout, np.random.default_rng(streams[1]), distortion).samples
        samples = simulation.samples
        if self.spikes:
            samples = add_spikes(samples, simulation.field_strength, np.random.default_rng(streams[2]))
        return simulation, samples, heldout


#: The aircraft's fields at a cabin or wing-root vector magnetometer, as fractions of the Earth's field (and
#: seconds for the eddy currents): permanent U(−0.4, 0.4), induced scales within ±3 % and cross terms within
#: ±1.5 %, eddy-current coefficients N(0, 0.01 s) (at a 30°/s turn, a few tenths of a per cent of the field).
AIRCRAFT_INDUCED = (0.03, 0.015)
AIRCRAFT_EDDY_S = 0.01


def aircraft_distortion(rng: np.random.Generator) -> tuple[NDArray[np.float64], ...]:
    """An aircraft's own field at its magnetometer, (W, V, E): Tolles–Lawson's three terms as eq. (1e) has them.

    Permanent V (the magnetised airframe), induced W − I (iron magnetised by the Earth's field: proportional
    to its direction cosines, symmetric) and eddy currents E (proportional to their rate of change as the
    aircraft manoeuvres; seconds). W and V are what a calibration can hold; E is not. B = 1.
    """
    scale, cross_limit = AIRCRAFT_INDUCED
    cross = rng.uniform(-cross_limit, cross_limit, 3)
    soft_iron = np.diag(1.0 + rng.uniform(-scale, scale, 3))
    soft_iron[[0, 0, 1], [1, 2, 2]] = cross
    soft_iron[[1, 2, 2], [0, 0, 1]] = cross
    return soft_iron, rng.uniform(-0.4, 0.4, 3), rng.normal(0.0, AIRCRAFT_EDDY_S, (3, 3))


def add_spikes(
    samples: NDArray[np.float64], field_strength: float, rng: np.random.Generator, fraction: float = SPIKE_FRACTION
) -> NDArray[np.float64]:
    """A copy of ``samples`` (N, 3) with ``fraction`` of them displaced by a random spike.

    Each spike has a uniformly random direction and a length uniform in ``SPIKE_RANGE`` × ``field_strength``.
    """
    spiked = samples.copy()
    count = round(fraction * len(samples))
    rows = rng.choice(len(samples), count, replace=False)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    lengths = rng.uniform(*SPIKE_RANGE, count) * field_strength
    spiked[rows] += directions * lengths[:, None]
    return spiked


def full_grid(trials_scale: float = 1.0) -> list[Case]:
    """The benchmark's grid (see the module docstring of the results for why it is not a full product).

    Noise sweep 0.5, 2, 5, 10 % at N = 10 000; N sweep 100 … 100 000 at 10 % and at 2 % noise; the special
    scenarios (restricted attitude, 2 % spikes, the paper's steel and smartphone cases) at N = 1000, and
    the level flight with a drifting field at N = 10 000 (:func:`flight_case`). Trial counts fall
    with N so that each size costs about the same.
    """
    trials = {100: 100, 1000: 50, 10_000: 24, 100_000: 14}

    def count(n: int) -> int:
        return max(2, round(trials[n] * trials_scale))

    cases: list[Case] = []
    for noise in (0.005, 0.02, 0.05, 0.10):
        n = 10_000
        cases.append(
            Case(f"tumble σ={noise * 100:g}% N={n}", n, noise, trials=count(n), seed_key=f"generic-{noise}-{n}")
        )
    for noise in (0.10, 0.02):
        for n in (100, 1000, 100_000):
            cases.append(
                Case(f"tumble σ={noise * 100:g}% N={n}", n, noise, trials=count(n), seed_key=f"generic-{noise}-{n}")
            )
    n = 1000
    cases.append(
        Case(f"restricted ±20° σ=2% N={n}", n, 0.02, orientations="restricted", trials=count(n), seed_key="restricted")
    )
    cases.append(
        Case(f"tumble σ=2% N={n} + 2% spikes", n, 0.02, spikes=True, trials=count(n), seed_key=f"generic-0.02-{n}")
    )
    cases.append(flight_case(trials=max(2, round(12 * trials_scale))))
    cases.append(aircraft_case(trials=max(2, round(20 * trials_scale))))
    for sensor in ("mpu9250", "ellipse2a"):
        for disturbance in ("steel", "smartphone"):
            cases.append(
                Case(
                    f"paper {sensor}/{disturbance} N={n}",
                    n,
                    None,
                    paper=(sensor, disturbance),
                    trials=count(n),
                    seed_key=f"paper-{sensor}-{disturbance}",
                )
            )
    return _ordered(cases)


def flight_case(n: int = 10_000, trials: int = 12, heldout: int = HELDOUT_SAMPLES) -> Case:
    """The vehicle case: level flight with turns (roll, pitch ±15°), the field drifting ±0.5 %.

    A new mild sensor each trial (:func:`mild_distortion`), noise 0.5 % of the field. The drift is real
    model error: the BIC alone then prefers the full model, whose extra parameters fit the drift.
    """
    return Case(
        f"level flight ±15° + field drift ±0.5% σ=0.5% N={n}",
        n,
        0.005,
        orientations="flight",
        trials=trials,
        seed_key="flight-drift",
        heldout=heldout,
        max_tilt_deg=15.0,
        field_drift=0.005,
        sensor="mild",
    )


def aircraft_case(n: int = 10_000, trials: int = 20, heldout: int = HELDOUT_SAMPLES) -> Case:
    """An aircraft-like flight: level legs and banked turns (±20°), 10 Hz, the field drifting ±0.5 %, and the
    aircraft's own permanent, induced and eddy-current fields (:func:`aircraft_distortion`), new each trial.

    The richer models follow the induced field (they predict held-out stretches better) but the samples do
    not determine them; ``auto`` must answer with the model they do determine, weak, with a heading
    one-sigma that covers its error.
    """
    return Case(
        f"aircraft ±20° + induced, eddy fields, drift ±0.5% σ=0.5% N={n}",
        n,
        0.005,
        orientations="flight",
        trials=trials,
        seed_key="aircraft",
        heldout=heldout,
        max_tilt_deg=20.0,
        field_drift=0.005,
        sensor="aircraft",
    )


def smoke_grid() -> list[Case]:
    """A tiny grid for the test: three cases, two trials each, seconds to run."""
    return [
        Case("tumble σ=0.5% N=1000", 1000, 0.005, trials=2, seed_key="smoke-tumble", heldout=2000),
        Case(
            "restricted ±20° σ=2% N=300",
            300,
            0.02,
            orientations="restricted",
            trials=2,
            seed_key="smoke-restricted",
            heldout=2000,
        ),
        flight_case(n=2000, trials=2, heldout=2000),
    ]


def _ordered(cases: list[Case]) -> list[Case]:
    """Sweeps first (by noise, then N), the special scenarios after."""

    def key(case: Case) -> tuple[int, float, int]:
        special = case.paper is not None or case.spikes or not case.full_tumble
        return (int(special), -(case.noise or 0.0) if not special else 0.0, case.n)

    return sorted(cases, key=key)


# ====================================================================== metrics

# The heading metric lives in _common.py (campaign.py and the tests score with it too); named here as before.


def offset_error(calibration: magfit.Calibration, simulation: magfit.Simulation) -> float:
    """``|V_fit − V_true| / B``, dimensionless."""
    return float(np.linalg.norm(calibration.offset - simulation.truth.offset) / simulation.field_strength)


def normalized_shape(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """``A / det(A)^(1/3)`` with ``A = matrixᵀ matrix``: the ellipsoid's shape without its scale."""
    shape = matrix.T @ matrix
    return shape / np.linalg.det(shape) ** (1.0 / 3.0)


def shape_error(calibration: magfit.Calibration, simulation: magfit.Simulation) -> float:
    """``‖Â − Â_true‖_F / ‖Â_true‖_F`` of the scale-free shapes (:func:`normalized_shape`)."""
    fitted = normalized_shape(calibration.matrix)
    true = normalized_shape(simulation.truth.matrix)
    return float(np.linalg.norm(fitted - true) / np.linalg.norm(true))


# ====================================================================== the floor


def _shape_from_parameters(theta: NDArray[np.float64]) -> NDArray[np.float64]:
    a = theta[3:]
    return np.array([[a[0], a[3], a[4]], [a[3], a[1], a[5]], [a[4], a[5], a[2]]])


def _parameters(simulation: magfit.Simulation) -> NDArray[np.float64]:
    """θ = (V, a): the offset and the six entries of A with ``(x − V)ᵀ A (x − V) = 1`` on the true ellipsoid."""
    shape = simulation.truth.ellipsoid_matrix
    return np.concatenate([simulation.truth.offset, shape[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]])


def geometric_scores(theta: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-point normal sensitivity g = (∂f/∂θ) / |∇ₓf| of ``f = (x − V)ᵀ A (x − V) − 1``, shape (N, 9).

    For a point x on the ellipsoid plus noise ``ε ~ N(0, σ² I)``, with the point's position on the
    surface a nuisance parameter, the Fisher information about θ is ``g gᵀ / σ²``: the tangential
    components of ``∂x/∂θ`` are absorbed by the nuisance, only the normal one, ``−(∂f/∂θ)/|∇ₓf|``, is left.
    """
    shape = _shape_from_parameters(theta)
    d = points - theta[:3]
    gradient = d @ shape  # ½ ∇ₓf (A symmetric)
    d_offset = -2.0 * gradient  # ∂f/∂V
    d_shape = np.column_stack(
        [d[:, 0] ** 2, d[:, 1] ** 2, d[:, 2] ** 2, 2 * d[:, 0] * d[:, 1], 2 * d[:, 0] * d[:, 2], 2 * d[:, 1] * d[:, 2]]
    )
    return np.column_stack([d_offset, d_shape]) / (2.0 * np.linalg.norm(gradient, axis=1, keepdims=True))


def unit_fisher_information(theta: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Expected Fisher information of one sample at noise σ = 1, ``E[g gᵀ]`` over ``points`` (9, 9)."""
    scores = geometric_scores(theta, points)
    return scores.T @ scores / len(points)


def heading_jacobian(simulation: magfit.Simulation, n_headings: int = N_HEADINGS) -> NDArray[np.float64]:
    """∂(heading difference, degrees)/∂θ at the truth by central differences, shape (n_headings, 9).

    The heading is computed exactly as the metric does (symmetric root of A, best rotation), so the
    propagation includes the rotation the metric forgives.
    """
    theta = _parameters(simulation)
    raw = level_readings(simulation, n_headings)
    steps = 1e-6 * np.concatenate([np.full(3, simulation.field_strength), np.full(6, np.abs(theta[3:6]).max())])

    def headings(parameters: NDArray[np.float64]) -> NDArray[np.float64]:
        values, vectors = np.linalg.eigh(_shape_from_parameters(parameters))
        root = (vectors * np.sqrt(values)) @ vectors.T
        return heading_differences_deg(parameters[:3], root, simulation, raw)

    columns = []
    for index, step in enumerate(steps):
        delta = np.zeros(9)
        delta[index] = step
        columns.append((headings(theta + delta) - headings(theta - delta)) / (2.0 * step))
    return np.column_stack(columns)


def cramer_rao_heading_deg(case: Case, n_points: int = 200_000, seed: int = 7) -> float:
    """Cramér–Rao floor of the calibration heading error of ``case``, degrees.

    Fisher information ``F = N E[g gᵀ] / σ²`` of the geometric noise model (:func:`geometric_scores`),
    expectation over ``n_points`` noise-free samples of the case's attitude distribution; the delta
    method gives ``E[mean_k δh_k²] ≈ mean_k (J F⁻¹ Jᵀ)_kk`` with J = :func:`heading_jacobian`. It bounds
    unbiased estimators; quantisation (MPU-9250 counts) is ignored (it adds 1/12 count² to σ² = 41).
    """
    simulation = Case(case.name, n_points, 0.0, case.orientations, paper=case.paper).simulate(
        n_points, np.random.default_rng(seed)
    )
    theta = _parameters(simulation)
    information = unit_fisher_information(theta, simulation.clean)
    jacobian = heading_jacobian(simulation)
    covariance = np.linalg.inv(information) * case.noise_std**2 / case.n
    return float(np.sqrt(np.mean(np.einsum("ki,ij,kj->k", jacobian, covariance, jacobian))))


# ====================================================================== running the methods


@dataclass
class Outcome:
    """The scores of one method on one trial (or the reason it failed)."""

    heading_deg: float | None = None
    offset_error: float | None = None
    shape_error: float | None = None
    fit_mean: float | None = None
    fit_std: float | None = None
    heldout_mean: float | None = None
    heldout_std: float | None = None
    seconds: float | None = None
    error: str | None = None
    details: dict[str, Any] | None = None
    #: magfit's support verdict on the trial: "supported", "weak" or "refused" (None for a peer).
    verdict: str | None = None
    #: Its first refusal, else its first weakness (the words the user would read).
    verdict_reason: str | None = None
    #: The heading one-sigma the fit states (``diagnostics.uncertainty.heading_sigma_deg``), degrees.
    stated_heading_deg: float | None = None
    #: Flight cases: the heading error over the attitudes the trial flew (``aircraft.attitude_heading_error_deg``),
    #: where "never worse than no calibration" is judged; None elsewhere.
    flown_deg: float | None = None


Fitter = Callable[[NDArray[np.float64], Any], magfit.Calibration]
#: The entries of a calibration's ``details`` kept in the results (auto's choice and its reasons).
KEPT_DETAILS = ("chosen", "method_used", "weak", "reason", "n_rejected", "support")
#: The pseudo-method of the heading table: no calibration at all (offset 0, identity matrix).
UNCALIBRATED = "uncalibrated"
#: Methods fitted without ``allow_undetermined``: a refusal of these is their result, not a failure to force.
NOT_FORCED = ("auto",)
#: Column order: the paper's three methods, then the unbiased, restricted, robust and automatic ones.
PREFERRED_ORDER = ("ellipsoid", "sphere", "minmax", "als", "ml", "diag", "robust", "auto")


def method_table(methods: Sequence[str] | None, peers: bool) -> dict[str, Fitter]:
    """The fitters to run, by column name: magfit's methods (``magfit.METHODS`` order) then the peers."""
    table: dict[str, Fitter] = {}
    ordered = [name for name in PREFERRED_ORDER if name in magfit.METHODS]
    for name in ordered + [name for name in magfit.METHODS if name not in ordered]:
        if magfit.METHODS[name].needs:  # vector, gyro: they need the vehicle's streams (accuracy_vehicle.py)
            continue
        if methods is None or name in methods:
            table[name] = _magfit_fitter(name)
    if peers:
        from peers import PEERS  # the sibling module; imported here so that magfit-only runs need no peer

        for name, peer in PEERS.items():
            if methods is None or name in methods:
                table[name] = peer.run
    return table


def _magfit_fitter(name: str) -> Fitter:
    """``magfit.fit`` of one method. Forced (``allow_undetermined=True``) except ``auto``: the tables measure
    what each method gives, and its verdict is recorded beside (:func:`verdict_of`); ``auto``'s refusal
    is its answer and counts as a failure."""
    forced = name not in NOT_FORCED

    def run(samples: NDArray[np.float64], context: Any) -> magfit.Calibration:
        return magfit.fit(samples, method=name, allow_undetermined=forced)

    return run


def fit_once(
    fitter: Fitter, samples: NDArray[np.float64], context: Any
) -> tuple[magfit.Calibration | None, str, float]:
    """Run one fitter; returns (calibration or None, failure message, seconds). Never raises."""
    start = time.perf_counter()
    try:
        calibration = fitter(samples, context)
    except Exception as error:  # a failing method is a result, recorded with its reason
        return None, _failure_message(error), time.perf_counter() - start
    return calibration, "", time.perf_counter() - start


def score(
    calibration: magfit.Calibration,
    simulation: magfit.Simulation,
    samples: NDArray[np.float64],
    heldout: NDArray[np.float64],
) -> Outcome:
    """Every metric of one fitted calibration."""
    fitted = magfit.evaluate(calibration, samples)
    unseen = magfit.evaluate(calibration, heldout)
    report = calibration.diagnostics
    stated = None if report is None or report.uncertainty is None else report.uncertainty.heading_sigma_deg
    return Outcome(
        stated_heading_deg=stated,
        heading_deg=heading_error_deg(calibration, simulation),
        offset_error=offset_error(calibration, simulation),
        shape_error=shape_error(calibration, simulation),
        fit_mean=fitted.mean,
        fit_std=fitted.std,
        heldout_mean=unseen.mean,
        heldout_std=unseen.std,
    )


def _peer_context(case: Case, simulation: magfit.Simulation) -> Any:
    from peers import PeerContext

    delta = np.radians(simulation.inclination_deg)
    field_vector = simulation.field_strength * np.array([np.cos(delta), 0.0, np.sin(delta)])
    return PeerContext(field_vector=field_vector, noise=case.noise_std)


def run_case(
    case: Case, fitters: Mapping[str, Fitter], root_seed: int, peers: bool, keep_details: Iterable[str] = ()
) -> dict[str, list[Outcome]]:
    """Every fitter on every trial of ``case`` (the same samples for all); outcomes by method name.

    ``outcomes[UNCALIBRATED]`` holds the heading error of no calibration on each trial.
    """
    outcomes: dict[str, list[Outcome]] = {name: [] for name in fitters}
    baseline: list[Outcome] = []
    keep = set(keep_details)
    flown = _flown_scorer() if case.orientations == "flight" else None
    for trial in range(case.trials):
        simulation, samples, heldout = case.trial_data(root_seed, trial)
        context = _peer_context(case, simulation) if peers else None
        for name, fitter in fitters.items():
            calibration, error, seconds = fit_once(fitter, samples, context)
            if calibration is None:
                outcome = Outcome(error=error)
            else:
                outcome = score(calibration, simulation, samples, heldout)
                if flown is not None:
                    outcome.flown_deg = flown(calibration, simulation, simulation.attitudes)
                if name in keep:
                    outcome.details = kept_details(calibration, KEPT_DETAILS)
            if name in magfit.METHODS:
                # A forced method that raises failed to fit (no convergence, a hyperboloid): no verdict.
                outcome.verdict, outcome.verdict_reason = verdict_of(calibration, error if name in NOT_FORCED else "")
            outcome.seconds = seconds
            outcomes[name].append(outcome)
        # What the raw readings give, as the yardstick a calibration must beat.
        uncalibrated = magfit.Calibration(UNCALIBRATED, np.zeros(3), np.eye(3), simulation.field_strength)
        baseline.append(Outcome(
            heading_deg=heading_error_deg(uncalibrated, simulation),
            flown_deg=None if flown is None else flown(uncalibrated, simulation, simulation.attitudes),
        ))  # fmt: skip
    outcomes[UNCALIBRATED] = baseline
    return outcomes


def _flown_scorer() -> Callable[[magfit.Calibration, magfit.Simulation, NDArray[np.float64]], float]:
    """The aircraft benchmark's heading error over a set of attitudes (one definition for both benchmarks).

    Imported when a flight case runs: ``aircraft`` imports this module for its case.
    """
    from aircraft import attitude_heading_error_deg

    return attitude_heading_error_deg


# ====================================================================== aggregation


@dataclass
class Summary:
    """One cell: a method on a case, aggregated over its trials."""

    trials: int
    failed: int
    heading_deg: float | None
    heading_sem: float | None
    offset_error: float | None
    shape_error: float | None
    fit_mean: float | None
    fit_std: float | None
    heldout_mean: float | None
    heldout_std: float | None
    seconds: float
    first_error: str | None = None
    errors: dict[str, int] = field(default_factory=dict)
    #: Trials by support verdict ("supported", "weak", "refused"); empty for a peer.
    verdicts: dict[str, int] = field(default_factory=dict)
    #: The first refusal and the first weakness named over the trials.
    first_refusal: str | None = None
    first_weakness: str | None = None


def _rms(values: Sequence[float]) -> float | None:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else None


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if len(values) else None


def summarise(outcomes: Sequence[Outcome]) -> Summary:
    """RMS over trials of the errors, mean of the sphere statistics, failures counted by message."""
    ok = [o for o in outcomes if o.error is None]
    errors: dict[str, int] = {}
    for outcome in outcomes:
        if outcome.error is not None:
            errors[outcome.error] = errors.get(outcome.error, 0) + 1
    verdicts: dict[str, int] = {}
    for outcome in outcomes:
        if outcome.verdict is not None:
            verdicts[outcome.verdict] = verdicts.get(outcome.verdict, 0) + 1
    headings = [o.heading_deg for o in ok if o.heading_deg is not None]
    rms = _rms(headings)
    # Standard error of an RMS by the delta method: sd(h²) / (2 rms √n).
    sem = None
    if rms and len(headings) > 1:
        sem = float(np.std(np.square(headings), ddof=1) / (2.0 * rms * np.sqrt(len(headings))))
    return Summary(
        trials=len(outcomes),
        failed=len(outcomes) - len(ok),
        heading_deg=rms,
        heading_sem=sem,
        offset_error=_rms([o.offset_error for o in ok if o.offset_error is not None]),
        shape_error=_rms([o.shape_error for o in ok if o.shape_error is not None]),
        fit_mean=_mean([o.fit_mean for o in ok if o.fit_mean is not None]),
        fit_std=_mean([o.fit_std for o in ok if o.fit_std is not None]),
        heldout_mean=_mean([o.heldout_mean for o in ok if o.heldout_mean is not None]),
        heldout_std=_mean([o.heldout_std for o in ok if o.heldout_std is not None]),
        seconds=float(np.mean([o.seconds or 0.0 for o in outcomes])),
        first_error=next((o.error for o in outcomes if o.error is not None), None),
        errors=errors,
        verdicts=verdicts,
        first_refusal=next((o.verdict_reason for o in outcomes if o.verdict == "refused"), None),
        first_weakness=next((o.verdict_reason for o in outcomes if o.verdict == "weak"), None),
    )


def floor_ratio(outcomes: Sequence[Outcome], floor: float) -> Ratio | None:
    """RMS heading error over the floor, with the standard error of the RMS."""
    summary = summarise(outcomes)
    if summary.heading_deg is None or not floor > 0:
        return None
    sem = summary.heading_sem if summary.heading_sem is not None else np.nan
    return Ratio(summary.heading_deg / floor, sem / floor, summary.trials - summary.failed)


# ====================================================================== targets


def weak_direction(details: Mapping[str, Any] | None) -> str | None:
    """The weakly determined direction a calibration's details name, if any.

    ``auto`` lists the weak directions of the model it chose under ``weak`` and, when it passed a richer
    model over, says in ``reason`` which direction the samples "do not determine". Any non-empty entry
    whose key mentions "weak" (searched through nested mappings), else such a sentence, counts.
    """
    if not details:
        return None
    stack: list[tuple[str, Any]] = list(details.items())
    sentences = []
    while stack:
        key, value = stack.pop(0)
        if isinstance(value, Mapping):
            stack.extend((f"{key}.{k}", v) for k, v in value.items())
            continue
        if "weak" in key.lower() and value not in (None, "", [], ()):
            return f"{key} = {value}"
        if isinstance(value, str) and "not determine" in value:
            sentences.append(f"{key}: {value}")
    return sentences[0] if sentences else None


def check_targets(cases: Sequence[Case], results: Mapping[str, Mapping[str, Sequence[Outcome]]]) -> list[Target]:
    """Evaluate the issue's targets on the results (``results[case.name][method]``)."""
    targets: list[Target] = []
    by_name = {case.name: case for case in cases}

    def have(case_name: str, *methods: str) -> bool:
        return case_name in results and all(m in results[case_name] for m in methods)

    def absent(what: str, methods: Iterable[str]) -> Target:
        return Target(what, "NOT RUN", f"needs methods {', '.join(methods)} and the matching case in the grid")

    def failures(case_name: str, method: str) -> str:
        summary = summarise(results[case_name][method])
        return f", {method} failed {summary.failed}/{summary.trials}" if summary.failed else ""

    # 1-2. The bias of the algebraic fit at 10 % noise.
    for n, limit in ((100_000, 0.5), (10_000, 0.75)):
        case_name = next((c.name for c in cases if c.gaussian and c.noise == 0.10 and c.n == n and not c.paper), "")
        for method in ("als", "ml"):
            what = f"σ=10%, N={n}: {method} ≤ {limit} × ellipsoid"
            if not have(case_name, method, "ellipsoid"):
                targets.append(absent(what, (method, "ellipsoid")))
                continue
            ratio = paired_ratio(results[case_name][method], results[case_name]["ellipsoid"])
            ok = ratio is not None and ratio.value <= limit
            detail = f"ratio {ratio} on {case_name}" + failures(case_name, method)
            targets.append(Target(what, _status(ok), detail))
    # 3. Nowhere on full-tumble data more than 5 % worse than ellipsoid.
    for method in ("als", "ml"):
        what = f"{method} ≤ 1.05 × ellipsoid on every full-tumble case"
        tumble = [c.name for c in cases if c.full_tumble and have(c.name, method, "ellipsoid")]
        if not tumble:
            targets.append(absent(what, (method, "ellipsoid")))
            continue
        ratios = {name: paired_ratio(results[name][method], results[name]["ellipsoid"]) for name in tumble}
        targets.append(_worst_target(what, ratios, 1.05, "worst ratio", {n: failures(n, method) for n in tumble}))
    # 4. ml within 15 % of the floor on every full-tumble (Gaussian) case.
    what = "ml ≤ 1.15 × Cramér–Rao floor on every full-tumble case (Gaussian noise)"
    gaussian = [c.name for c in cases if c.gaussian and have(c.name, "ml", "floor")]
    if not gaussian:
        targets.append(absent(what, ("ml",)))
    else:
        ratios = {
            name: floor_ratio(results[name]["ml"], results[name]["floor"][0].heading_deg or 0.0) for name in gaussian
        }
        targets.append(_worst_target(what, ratios, 1.15, "worst ml/floor", {n: failures(n, "ml") for n in gaussian}))
    # 5. robust with 2 % spikes vs the same samples without.
    what = "robust with 2% spikes ≤ 1.25 × robust on the same samples without spikes"
    spiked = next((c for c in cases if c.spikes), None)
    twin = next((c for c in cases if spiked and not c.spikes and c.seed_key == spiked.seed_key), None)
    if spiked is None or twin is None or not have(spiked.name, "robust") or not have(twin.name, "robust"):
        targets.append(absent(what, ("robust",)))
    else:
        ratio = paired_ratio(results[spiked.name]["robust"], results[twin.name]["robust"])
        with_spikes = summarise(results[spiked.name]["robust"]).heading_deg
        without = summarise(results[twin.name]["robust"]).heading_deg
        detail = f"{_fmt_deg(with_spikes)} with vs {_fmt_deg(without)} without: ratio {ratio}"
        targets.append(Target(what, _status(ratio is not None and ratio.value <= 1.25), detail))
    # 6. auto on restricted attitude, against the forced fits of the three models.
    for case in (c for c in cases if c.orientations == "restricted"):
        what = f"{case.name}: auto ≤ 1.2 × best of sphere, diag, full (forced); names the weak direction"
        if not have(case.name, "auto", "sphere", "diag"):
            targets.append(absent(what, ("auto", "sphere", "diag")))
            continue
        comparison = _auto_against_models(results[case.name])
        named = [weak_direction(o.details) for o in results[case.name]["auto"] if o.error is None]
        named_count = sum(1 for text in named if text)
        example = next((text for text in named if text), "none")
        ok = comparison.ok and named_count == len(named) and named_count > 0
        detail = f"{comparison.detail}; weak direction named in {named_count}/{len(named)} fitted trials"
        detail += f" (e.g. {example})"
        targets.append(Target(what, _status(ok), detail, items=comparison.items))
    # 6b. auto on level flight with a drifting field, and the aircraft. "Never worse than no calibration" is
    # judged on the attitudes each trial flew, as benchmarks/aircraft.py judges it: at level the raw readings
    # ignore the offset along the sensor's z axis, which leans into the heading once the aircraft banks (its
    # module docstring). The level-only comparison is listed beside it.
    for case in (c for c in cases if c.orientations == "flight"):
        what = (
            f"{case.name}: auto ≤ 1.2 × best of sphere, diag, full (forced), and per trial ≤ no calibration over "
            "the attitudes flown"
        )
        if not have(case.name, "auto", "sphere", "diag", UNCALIBRATED):
            targets.append(absent(what, ("auto", "sphere", "diag")))
            continue
        comparison = _auto_against_models(results[case.name])
        worse = {key: _worse_than_none(results[case.name], key) for key in ("flown_deg", "heading_deg")}
        uncalibrated = summarise(results[case.name][UNCALIBRATED]).heading_deg
        detail = (
            f"{comparison.detail}; no calibration {_fmt_deg(uncalibrated)} (level); auto above no calibration (or "
            f"refused) on {len(worse['flown_deg'])}/{case.trials} trials over the attitudes flown (level only, "
            f"listed, not the target: {len(worse['heading_deg'])}/{case.trials})"
        )
        items = comparison.items + worse["flown_deg"] + [f"level only: {item}" for item in worse["heading_deg"]]
        targets.append(Target(what, _status(comparison.ok and not worse["flown_deg"]), detail, items=items))
    # 6c. auto's stated heading one-sigma covers its error (the aircraft: a distortion it must leave out).
    for case in (c for c in cases if c.sensor == "aircraft"):
        what = f"{case.name}: auto's stated heading one-sigma ≥ its heading error on ≥ 90 % of trials"
        if not have(case.name, "auto"):
            targets.append(absent(what, ("auto",)))
            continue
        targets.append(coverage_target(what, results[case.name]["auto"]))
    # 7. every magfit method at least as accurate as the best peer.
    targets.append(_peer_target(results, by_name))
    return targets


def _worse_than_none(outcomes: Mapping[str, Sequence[Outcome]], key: str) -> list[str]:
    """The trials where auto's heading error ``key`` (``flown_deg`` or ``heading_deg``) exceeds no calibration's."""
    pairs = zip(outcomes["auto"], outcomes[UNCALIBRATED], strict=True)
    return [
        f"trial {trial}: auto {_fmt_deg(getattr(mine, key))} vs none {_fmt_deg(getattr(none, key))}"
        for trial, (mine, none) in enumerate(pairs)
        if getattr(mine, key) is None or getattr(none, key) is None or getattr(mine, key) > getattr(none, key)
    ]


def coverage_target(what: str, outcomes: Sequence[Outcome], share: float = 0.9) -> Target:
    """Whether the stated heading one-sigma covers the heading error on at least ``share`` of the trials.

    A trial refused (no calibration, no statement) counts as not covered; the items list each trial's
    error against its statement.
    """
    covered = [
        o.heading_deg is not None and o.stated_heading_deg is not None and o.heading_deg <= o.stated_heading_deg
        for o in outcomes
    ]
    items = [
        f"trial {trial}: error {_fmt_deg(o.heading_deg)} vs stated ±{_fmt_deg(o.stated_heading_deg)}"
        + ("" if ok else " NOT COVERED")
        for trial, (o, ok) in enumerate(zip(outcomes, covered, strict=True))
    ]
    ratios = [o.heading_deg / o.stated_heading_deg for o in outcomes if o.heading_deg and o.stated_heading_deg]
    detail = (
        f"covered on {sum(covered)}/{len(outcomes)} trials; error / stated one-sigma: median "
        f"{np.median(ratios) if ratios else float('nan'):.2f}, worst {max(ratios, default=float('nan')):.2f}"
    )
    return Target(what, _status(len(outcomes) > 0 and sum(covered) >= share * len(outcomes)), detail, items=items)


#: The methods that fit the full model: auto's full candidate is the maximum-likelihood ellipsoid (``ml``);
#: ``als`` is the other consistent one. The algebraic ``ellipsoid`` is not what ``auto`` could choose.
FULL_MODEL_METHODS = ("als", "ml")


@dataclass(frozen=True)
class AutoComparison:
    """``auto`` against the best forced fit of the sphere, diag and full models on one case."""

    ok: bool
    detail: str
    items: list[str]


def _auto_against_models(per_case: Mapping[str, Sequence[Outcome]], limit: float = 1.2) -> AutoComparison:
    """RMS heading error of ``auto`` over that of the best of sphere, diag and the full model (forced fits).

    ``auto`` must have fitted every trial (a refusal where the forced fits are accurate is a regression)
    and be within ``limit`` times the best. The items list every model's error and verdicts, and auto's
    choices and refusals.
    """
    candidates = [m for m in ("sphere", "diag", *FULL_MODEL_METHODS) if m in per_case]
    summaries = {m: summarise(per_case[m]) for m in candidates}
    fitted = [(m, s.heading_deg) for m, s in summaries.items() if s.heading_deg is not None and s.failed == 0]
    best_name, best_value = min(fitted, key=lambda item: item[1], default=("none", None))
    auto = summarise(per_case["auto"])
    against = paired_ratio(per_case["auto"], per_case[best_name]) if best_name in per_case else None
    chosen = sorted({str((o.details or {}).get("chosen")) for o in per_case["auto"] if o.details})
    ok = against is not None and against.value <= limit and auto.failed == 0
    detail = (
        f"auto {_fmt_deg(auto.heading_deg)} vs best {best_name} {_fmt_deg(best_value)}: paired ratio "
        f"{against or '—'}; auto refused {auto.verdicts.get('refused', 0)}/{auto.trials}, weak "
        f"{auto.verdicts.get('weak', 0)}/{auto.trials}; auto chose {', '.join(chosen) or '—'}"
    )
    items = []
    for method, summary in summaries.items():
        verdicts = ", ".join(f"{k} {v}" for k, v in sorted(summary.verdicts.items())) or "no verdict"
        failed = f", {summary.failed}/{summary.trials} failed ({summary.first_error})" if summary.failed else ""
        items.append(f"{method} (forced): {_fmt_deg(summary.heading_deg)}; verdicts: {verdicts}{failed}")
    if auto.failed:
        items.append(f"auto failed {auto.failed}/{auto.trials} trials, first: {auto.first_error}")
    if auto.first_weakness:
        items.append(f"auto's first weakness named: {auto.first_weakness}")
    return AutoComparison(ok, detail, items)


def _worst_target(
    what: str, ratios: Mapping[str, Ratio | None], limit: float, label: str, notes: Mapping[str, str]
) -> Target:
    """A target that every case must meet: the worst ratio, and every case over the limit."""
    bad = {name: r for name, r in ratios.items() if r is None or r.value > limit}
    worst = max(ratios.items(), key=lambda item: item[1].value if item[1] is not None else np.inf)
    detail = f"{label} {worst[1] or '—'} ({worst[0]}{notes.get(worst[0], '')})"
    if bad:
        detail += f"; over {limit} on: " + "; ".join(
            f"{name} ({r or '—'}{notes.get(name, '')})" for name, r in bad.items()
        )
    return Target(what, _status(not bad), detail)


def _peer_target(results: Mapping[str, Mapping[str, Sequence[Outcome]]], cases: Mapping[str, Case]) -> Target:
    """Every magfit method at least as accurate as the best peer, case by case.

    A loss smaller than twice the standard error of the difference is listed as within noise and does
    not fail the target; every loss is listed with the reason the method's model gives for it. A forced
    fit that magfit's verdict refused on every trial of the case is listed apart and does not fail the
    target either: without ``allow_undetermined`` the user gets the refusal, not that number.
    """
    what = "every magfit method ≤ best peer (heading error), on every case"
    peer_names = {m for per_case in results.values() for m in per_case if "." in m}
    if not peer_names:
        return Target(what, "NOT RUN", "no peer ran")
    losses: dict[str, list[str]] = {}
    within_noise: list[str] = []
    refused: list[str] = []
    for case_name, per_case in results.items():
        peers = {m: summarise(o) for m, o in per_case.items() if m in peer_names}
        fitted = [(m, s) for m, s in peers.items() if s.heading_deg is not None and s.failed == 0]
        if not fitted:
            continue
        best_peer, best = min(fitted, key=lambda item: item[1].heading_deg or 0.0)
        assert best.heading_deg is not None
        for method in per_case:
            if method in peer_names or method in ("floor", UNCALIBRATED):
                continue
            mine = summarise(per_case[method])
            if mine.heading_deg is not None and mine.failed == 0 and mine.heading_deg <= best.heading_deg:
                continue
            failed = f", {mine.failed}/{mine.trials} failed" if mine.failed else ""
            line = f"{case_name} ({_fmt_deg(mine.heading_deg)}{failed} vs {best_peer} {_fmt_deg(best.heading_deg)})"
            noise = 2.0 * float(np.hypot(mine.heading_sem or 0.0, best.heading_sem or 0.0))
            if mine.heading_deg is not None and mine.failed == 0 and mine.heading_deg - best.heading_deg <= noise:
                within_noise.append(f"{method} on {line}: within 2 standard errors ({noise:.2g}°)")
            elif method not in NOT_FORCED and mine.verdicts.get("refused", 0) == mine.trials:
                refused.append(f"{method} on {line}: refused by the verdict on every trial (forced here)")
            else:
                losses.setdefault(method, []).append(line)
    items = [
        f"**{method}** loses on {len(lines)} case(s) — {_why(method)}: " + "; ".join(lines)
        for method, lines in losses.items()
    ]
    items += [f"{line} (not counted as a loss)" for line in within_noise + refused]
    count = sum(len(lines) for lines in losses.values())
    detail = (
        f"{count} loss(es) beyond noise by {', '.join(losses) or 'no method'}; {len(within_noise)} within noise"
        f"; {len(refused)} refused by magfit's verdict (listed below)"
        if losses or within_noise or refused
        else "every magfit method at least as accurate as the best peer on every case"
    )
    return Target(what, _status(not losses), detail, items=items)


#: Why a method's model can make it lose to a peer's full ellipsoid fit (for the report).
_MODEL_LIMITS = {
    "sphere": "hard iron only: it cannot correct soft iron",
    "minmax": "per-axis pseudo-calibration: it ignores rotated soft iron and is biased by uneven coverage",
    "diag": "axis-aligned soft iron only: the simulated soft iron is rotated",
    "ellipsoid": "the algebraic fit is biased when the noise is large or the coverage partial",
}


def _why(method: str) -> str:
    """The reason a method's model gives for losing, or a pointer to its owner when it has none."""
    return _MODEL_LIMITS.get(method, "its model covers these cases: an accuracy issue for the method's owner")


# ====================================================================== real recordings


@dataclass(frozen=True)
class Recording:
    """A real recording and how to read its x, y, z columns."""

    path: str
    columns: tuple[int, int, int] | tuple[str, str, str]
    delimiter: str | None = ","
    skip_lines: int = 0
    drop_first: int = 0
    failure_case: bool = False


RECORDINGS = (
    Recording("fxos8700_magneto/mag-readings.txt", (0, 1, 2), delimiter=None),
    Recording("unc_qmc5883l/filtered_raw_data.csv", ("mx", "my", "mz"), skip_lines=2, drop_first=3000),
    Recording("betaflight_apex5_qmc5883/20231014_apex5_mag_on_tpu_03.txt", (0, 1, 2)),
    Recording("betaflight_apex5_qmc5883/20231008_apex5_mag_on_tpu_00.txt", (0, 1, 2)),
    Recording("mxl_umich_mpu9250_rm3100/preflight_data_original_imu.csv", ("imu_mx", "imu_my", "imu_mz")),
    Recording("mxl_umich_mpu9250_rm3100/preflight_data_original_pni.csv", ("mag_x", "mag_y", "mag_z")),
    Recording("mxl_umich_mpu9250_rm3100/test0_esti_trunc.csv", ("mag_x", "mag_y", "mag_z")),
    Recording("animaltrack_missionbay/missionbay_calib2_converted.csv", ("mx_raw", "my_raw", "mz_raw")),
    Recording("animaltrack_missionbay/missionbay2_converted.csv", ("mx_raw", "my_raw", "mz_raw")),
    Recording("gyrolib_rahrs/calibrationGyroLib_converted.csv", ("Mx", "My", "Mz")),
    Recording("hamagure_gauss/data-set_1.csv", ("x", "y", "z")),
    Recording("hamagure_gauss/data-set_2.csv", ("x", "y", "z")),
    Recording("ensta_tlefloch_imu/mag_data.txt", (0, 1, 2), delimiter=None),
    Recording("android_phone_kritiksoman/data_mag.txt", ("x", "y", "z"), failure_case=True),
    Recording("hmc5883l_nliaudat_partial/mag_out_sample.txt", (0, 1, 2), failure_case=True),
)


def read_recording(folder: Path, recording: Recording) -> NDArray[np.float64]:
    """The (N, 3) samples of ``recording`` under ``folder``, in the file's units."""
    path = folder / recording.path
    skip = recording.skip_lines
    columns = recording.columns
    if isinstance(columns[0], str):
        with path.open(encoding="utf-8-sig") as handle:
            lines = [handle.readline() for _ in range(skip + 1)]
        header = [name.strip() for name in lines[-1].split(recording.delimiter)]
        indices = tuple(header.index(str(name)) for name in columns)
        skip += 1
    else:
        indices = tuple(int(index) for index in columns)
    data = np.loadtxt(
        path, delimiter=recording.delimiter, skiprows=skip, usecols=indices, encoding="utf-8-sig", ndmin=2
    )
    return np.asarray(data[recording.drop_first :], dtype=np.float64)


def run_recordings(folder: Path, fitters: Mapping[str, Fitter], seed: int) -> dict[str, dict[str, Any]]:
    """Fit each method on a random half of each recording; held-out sphere std on the other half."""
    table: dict[str, dict[str, Any]] = {}
    for recording in RECORDINGS:
        try:
            samples = read_recording(folder, recording)
        except (OSError, ValueError) as error:
            table[recording.path] = {"error": f"cannot read: {_failure_message(error)}"}
            continue
        order = np.random.default_rng([seed, zlib.crc32(recording.path.encode())]).permutation(len(samples))
        half = len(samples) // 2
        fit_part, heldout = samples[order[:half]], samples[order[half:]]
        row: dict[str, Any] = {"n": len(samples), "failure_case": recording.failure_case, "methods": {}}
        for name, fitter in fitters.items():
            calibration, message, seconds = fit_once(fitter, fit_part, None)
            unforced = message if name in NOT_FORCED else ""
            verdict, reason = verdict_of(calibration, unforced) if name in magfit.METHODS else (None, None)
            judged = {"verdict": verdict, "verdict_reason": reason} if verdict else {}
            if calibration is None:
                row["methods"][name] = {"error": message, "seconds": seconds, **judged}
                continue
            try:
                unseen = magfit.evaluate(calibration, heldout)
                fitted = magfit.evaluate(calibration, fit_part)
            except magfit.MagfitError as failure:
                row["methods"][name] = {"error": _failure_message(failure), "seconds": seconds, **judged}
                continue
            row["methods"][name] = {"heldout_std": unseen.std, "fit_std": fitted.std, "seconds": seconds, **judged}
        table[recording.path] = row
    return table


# ====================================================================== report


def _fmt_deg(value: float | None) -> str:
    return "—" if value is None else f"{value:.3g}°"


def _fmt(value: float | None, scale: float = 1.0, digits: int = 3) -> str:
    return "—" if value is None else f"{value * scale:.{digits}g}"


def _cell(summary: Summary, text: str, notes: dict[str, int]) -> str:
    if summary.failed == summary.trials:
        return f"fails [{_note(notes, summary.first_error or 'failed')}]"
    if summary.failed:
        text += f" ({summary.failed}/{summary.trials} failed [{_note(notes, summary.first_error or 'failed')}])"
    return text


def _signed(value: float | None) -> str:
    return "—" if value is None else f"{value:+.2g}"


#: The simulated tables: title, cell text of a summary, whether the floor column is shown.
_TABLES: tuple[tuple[str, Callable[[Summary], str], bool], ...] = (
    ("Calibration heading error (degrees, RMS over level headings and trials)", lambda s: _fmt(s.heading_deg), True),
    ("Offset error |V − V_true| / B (%)", lambda s: _fmt(s.offset_error, 100.0), False),
    ("Shape error of A, scale removed (%)", lambda s: _fmt(s.shape_error, 100.0), False),
    (
        "Sphere distances on the fitted samples: mean / std (the paper's section V metric)",
        lambda s: f"{_signed(s.fit_mean)} / {_fmt(s.fit_std)}",
        False,
    ),
    (
        "Sphere distances on held-out samples: mean / std",
        lambda s: f"{_signed(s.heldout_mean)} / {_fmt(s.heldout_std)}",
        False,
    ),
    ("Seconds per fit (mean over trials)", lambda s: _fmt(s.seconds, 1.0, 2), False),
)


def render_markdown(report: Mapping[str, Any]) -> str:
    """The results file: header, grid, tables, targets, real recordings, footnotes."""
    cases = report["cases"]
    methods = report["methods"]
    summaries = report["summaries"]
    notes: dict[str, int] = {}
    lines = [
        "# magfit accuracy benchmark",
        "",
        f"Command: `{report['command']}`  ",
        f"Date (UTC): {report['date']}; runtime {report['runtime_s']:.0f} s on one core; root seed {report['seed']}  ",
        "Versions: " + ", ".join(f"{k} {v}" for k, v in report["versions"].items()),
        "",
        "Every method is fitted to the same samples in each trial; errors are RMS over the trials "
        "(`benchmarks/README.md` defines the metrics and explains the grid). "
        "`floor` is the Cramér–Rao bound of the heading error. `fails [k]`: every trial failed, for the "
        "reason in footnote k; `(j/n failed [k])`: j of the n trials failed and the number is over the rest.",
        "",
        "## Grid",
        "",
        "| case | N | noise σ / B | attitudes | trials |",
        "|---|---|---|---|---|",
    ]
    for case in cases:
        attitudes = _attitudes_text(case)
        lines.append(
            f"| {case['name']} | {case['n']} | {case['noise_fraction']:.4g} | {attitudes} | {case['trials']} |"
        )

    for title, text, with_floor in _TABLES:
        header = ["case"] + (["floor", UNCALIBRATED] if with_floor else []) + methods
        lines.extend(["", f"## {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)])
        if with_floor:
            lines[-2:-2] = [
                f"`{UNCALIBRATED}`: the raw readings (offset 0, identity matrix), scored alike. The floor is not "
                "defined where the sensor changes from trial to trial or the field drifts (—).",
                "",
            ]
        for case in cases:
            row = [case["name"]]
            if with_floor:
                row.append(_fmt(report["floors"].get(case["name"])))
                row.append(_fmt(_baseline_heading(summaries[case["name"]])))
            for method in methods:
                summary = summaries[case["name"]].get(method)
                row.append("not run" if summary is None else _cell(summary, text(summary), notes))
            lines.append("| " + " | ".join(row) + " |")

    lines.extend(_verdict_section(cases, methods, summaries, notes))

    lines.extend(["", "## Targets", "", "| target | result | numbers |", "|---|---|---|"])
    for target in report["targets"]:
        lines.append(f"| {target.name} | **{target.status}** | {target.detail} |")
    for target in report["targets"]:
        if target.items:
            lines.extend(["", f"{target.name}:", ""])
            lines.extend(f"- {item}" for item in target.items)

    if report.get("real"):
        lines.extend(_real_section(report["real"], methods, notes))

    if notes:
        lines.extend(["", "## Footnotes (failure and verdict reasons)", ""])
        lines.extend(f"{number}. {message.replace('|', '/')}" for message, number in notes.items())
    lines.append("")
    return "\n".join(lines)


def _attitudes_text(case: Mapping[str, Any]) -> str:
    """The grid's description of a case's attitudes and extras."""
    tilt = f"{case.get('max_tilt_deg', MAX_TILT_DEG):g}°"
    text = {
        "uniform": "full tumble",
        "restricted": f"full yaw, roll/pitch ±{tilt}",
        "flight": f"level flight with turns in time order, roll/pitch ±{tilt}",
    }.get(case["orientations"], case["orientations"])
    if case["spikes"]:
        text += ", 2 % spikes"
    if case.get("field_drift"):
        text += f", field strength drifting ±{case['field_drift'] * 100:g} % along the recording"
    if case.get("sensor") == "mild":
        text += ", a random mild sensor per trial (scales ±2 %, cross terms ±1 %, hard iron U(−0.4, 0.4)·B)"
    if case.get("sensor") == "aircraft":
        scale, cross = AIRCRAFT_INDUCED
        text += (
            f", a random aircraft per trial: permanent U(−0.4, 0.4)·B, induced scales ±{scale * 100:g} % and cross "
            f"terms ±{cross * 100:g} %, eddy currents N(0, {AIRCRAFT_EDDY_S:g} s) on the field's rate of change at "
            "10 Hz (Tolles–Lawson)"
        )
    return text


def _baseline_heading(per_case: Mapping[str, Summary]) -> float | None:
    summary = per_case.get(UNCALIBRATED)
    return None if summary is None else summary.heading_deg


def _verdict_section(
    cases: Sequence[Mapping[str, Any]],
    methods: Sequence[str],
    summaries: Mapping[str, Mapping[str, Summary]],
    notes: dict[str, int],
) -> list[str]:
    """The table of magfit's support verdicts: refused / weak trials per method and case."""
    magfit_methods = [m for m in methods if m in magfit.METHODS]
    lines = [
        "",
        "## Support verdict: refused / weak trials per method",
        "",
        'magfit judges every fit (`calibration.support`). The methods other than '
        + ", ".join(f"`{m}`" for m in NOT_FORCED)
        + " are fitted with `allow_undetermined=True`, so the tables above score what they give even where "
        "the samples do not support them; this table says how often that was. `auto` is not forced: its "
        "refusals are its failures above. Cell: refused / weak trials of the case's trials, `[k]` the first "
        "reason given (footnotes).",
        "",
        "| case | trials | " + " | ".join(magfit_methods) + " |",
        "|---|---|" + "---|" * len(magfit_methods),
    ]
    for case in cases:
        row = [case["name"], str(case["trials"])]
        for method in magfit_methods:
            summary = summaries[case["name"]].get(method)
            if summary is None:
                row.append("not run")
                continue
            refused, weak = summary.verdicts.get("refused", 0), summary.verdicts.get("weak", 0)
            reason = summary.first_refusal or summary.first_weakness
            cell = f"{refused} / {weak}"
            if reason:
                cell += f" [{_note(notes, reason)}]"
            row.append(cell)
        lines.append("| " + " | ".join(row) + " |")
    return lines


def _real_section(real: Mapping[str, Any], methods: Sequence[str], notes: dict[str, int]) -> list[str]:
    lines = [
        "",
        "## Real recordings: held-out sphere std",
        "",
        "Fitted on a random half of each recording; the std of the sphere distances on the other half "
        "(dimensionless, a fraction of the fitted field). The methods but `auto` are forced, as in the "
        "simulations: `refused [k]` / `weak [k]` beside a number is magfit's verdict on that fit, reason in "
        "footnote k. The two failure cases must be diagnosed, not fitted: their diagnoses are listed below "
        "the table.",
        "",
        "| recording | N | " + " | ".join(methods) + " |",
        "|---|---|" + "---|" * len(methods),
    ]
    for path, row in real.items():
        label = path + (" (failure case)" if row.get("failure_case") else "")
        if "error" in row:
            lines.append(f"| {label} | — | " + " | ".join(row["error"] for _ in methods) + " |")
            continue
        cells = []
        for method in methods:
            entry = row["methods"].get(method)
            if entry is None:
                cells.append("not run")
            elif "error" in entry:
                cells.append(f"fails [{_note(notes, entry['error'])}]")
            else:
                judged = ""
                if entry.get("verdict") in ("refused", "weak") and entry.get("verdict_reason"):
                    judged = f" ({entry['verdict']} [{_note(notes, entry['verdict_reason'])}])"
                cells.append(f"{entry['heldout_std']:.3g}{judged}")
        lines.append(f"| {label} | {row['n']} | " + " | ".join(cells) + " |")
    lines.extend(["", "### Diagnoses on the failure cases", ""])
    for path, row in real.items():
        if not row.get("failure_case") or "methods" not in row:
            continue
        for method in methods:
            entry = row["methods"].get(method, {})
            if "error" in entry:
                lines.append(f"- `{path}`, {method}: {entry['error']}")
            elif entry.get("verdict") == "refused":
                lines.append(
                    f"- `{path}`, {method}: refused by the verdict (returned only because forced): "
                    f"{entry.get('verdict_reason')}"
                )
            else:
                lines.append(
                    f"- `{path}`, {method}: **no diagnosis**, returned numbers (held-out std "
                    f"{entry.get('heldout_std', float('nan')):.3g})"
                )
    return lines


# ====================================================================== main


def run(
    cases: Sequence[Case],
    *,
    methods: Sequence[str] | None = None,
    peers: bool = True,
    real_data: Path | None = None,
    seed: int = 20261121,
    command: str = "",
    progress: Callable[[str], None] | None = None,
    floor_points: int = 200_000,
) -> dict[str, Any]:
    """Run the benchmark and return the report (what :func:`render_markdown` and the JSON are made of)."""
    start = time.perf_counter()
    found_versions = versions(peers)  # at the start: the commit the fits ran on
    fitters = method_table(methods, peers)
    results: dict[str, dict[str, list[Outcome]]] = {}
    floors: dict[str, float] = {}
    for case in cases:
        case_start = time.perf_counter()
        results[case.name] = run_case(case, fitters, seed, peers, keep_details=("auto", "diag", "robust"))
        if case.has_floor:
            floors[case.name] = cramer_rao_heading_deg(case, n_points=floor_points)
            results[case.name]["floor"] = [Outcome(heading_deg=floors[case.name])]
        if progress:
            progress(f"{case.name}: {case.trials} trials in {time.perf_counter() - case_start:.1f} s")
    summaries = {
        name: {method: summarise(outcomes) for method, outcomes in per_case.items() if method != "floor"}
        for name, per_case in results.items()
    }
    targets = check_targets(cases, results)
    real = None
    if real_data is not None and real_data.is_dir():
        real = run_recordings(real_data, fitters, seed)
        if progress:
            progress(f"real recordings: {len(real)} files")
    case_rows = [
        {**asdict(case), "noise_fraction": case.noise_std / case.field_strength, "full_tumble": case.full_tumble}
        for case in cases
    ]
    return {
        "command": command,
        "date": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "runtime_s": time.perf_counter() - start,
        "seed": seed,
        "versions": found_versions,
        "methods": list(fitters),
        "cases": case_rows,
        "floors": floors,
        "summaries": summaries,
        "outcomes": results,
        "targets": targets,
        "real": real,
    }


def _command_line(arguments: list[str]) -> str:
    """The command as typed from the checkout: thread settings, interpreter, script, arguments."""
    interpreter = Path(sys.executable)
    try:
        shown = str(interpreter.relative_to(ROOT))
    except ValueError:
        shown = "python"
    threads = [
        f"{name}={os.environ[name]}" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS") if name in os.environ
    ]
    return shlex.join([*threads, shown, "benchmarks/accuracy.py", *arguments])


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--output", type=Path, default=HERE / "results", help="folder for accuracy.md / .json")
    parser.add_argument("--smoke", action="store_true", help="tiny grid (two cases, two trials), no real data")
    parser.add_argument("--trials-scale", type=float, default=1.0, help="multiply every trial count")
    parser.add_argument("--no-peers", action="store_true", help="magfit's methods only")
    parser.add_argument("--methods", help="comma-separated subset of the methods (magfit names, peer names)")
    parser.add_argument("--real-data", type=Path, default=DEFAULT_REAL_DATA, help="folder of the real recordings")
    parser.add_argument("--no-real", action="store_true", help="skip the real recordings")
    parser.add_argument("--seed", type=int, default=20261121)
    parser.add_argument("--cases", help="comma-separated words: only the cases whose name contains one of them")
    parser.add_argument(
        "--vehicle",
        action="store_true",
        help="the vehicle scenarios instead (attitude-aided, alignment, gyro-aided; accuracy_vehicle.py); "
        "--output defaults to results/vehicle",
    )
    parser.add_argument(
        "--broad-data",
        type=Path,
        default=os.environ.get("MAGFIT_BROAD_DATA"),
        help="with --vehicle: BROAD's data_mat folder (git clone https://github.com/dlaidig/broad), real recordings "
        "with an optical attitude reference; default $MAGFIT_BROAD_DATA",
    )
    args = parser.parse_args(argv)

    command = _command_line(sys.argv[1:] if argv is None else list(argv))
    if args.vehicle:
        return _main_vehicle(args, command, parser)
    cases = smoke_grid() if args.smoke else full_grid(args.trials_scale)
    if args.cases:
        words = [word.strip() for word in args.cases.split(",") if word.strip()]
        cases = [case for case in cases if any(word in case.name for word in words)]
        if not cases:
            parser.error(f"--cases {args.cases!r} matches no case of the grid")
    methods = args.methods.split(",") if args.methods else None
    report = run(
        cases,
        methods=methods,
        peers=not args.no_peers,
        real_data=None if (args.no_real or args.smoke) else args.real_data,
        seed=args.seed,
        command=command,
        progress=lambda message: print(message, file=sys.stderr, flush=True),
        floor_points=20_000 if args.smoke else 200_000,
    )
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "accuracy.md").write_text(render_markdown(report), encoding="utf-8")
    (args.output / "accuracy.json").write_text(report_json(report), encoding="utf-8")
    print(f"wrote {args.output / 'accuracy.md'} and accuracy.json in {report['runtime_s']:.0f} s", file=sys.stderr)
    for target in report["targets"]:
        print(f"{target.status:8} {target.name}: {target.detail}", file=sys.stderr)
    return 0


def _main_vehicle(args: argparse.Namespace, command: str, parser: argparse.ArgumentParser) -> int:
    """``--vehicle``: the vehicle scenarios (the sibling module ``accuracy_vehicle``), written to their own folder."""
    import accuracy_vehicle as vehicle  # the sibling module (both import _common.py, not each other)

    cases = vehicle.vehicle_smoke_grid() if args.smoke else vehicle.vehicle_grid(args.trials_scale)
    if args.cases:
        words = [word.strip() for word in args.cases.split(",") if word.strip()]
        cases = [case for case in cases if any(word in case.name for word in words)]
        if not cases:
            parser.error(f"--cases {args.cases!r} matches no vehicle case")
    report = vehicle.run(
        cases,
        methods=args.methods.split(",") if args.methods else None,
        peers=not args.no_peers,
        seed=args.seed,
        command=command,
        progress=lambda message: print(message, file=sys.stderr, flush=True),
        broad_data=None if (args.smoke or args.no_real or args.broad_data is None) else Path(args.broad_data),
    )
    # Never over the main grid's accuracy.md: the main results folder, however it is spelled, means its vehicle/.
    main_results = (HERE / "results").resolve()
    output = main_results / "vehicle" if args.output.resolve() == main_results else args.output
    output.mkdir(parents=True, exist_ok=True)
    (output / "accuracy.md").write_text(vehicle.render_markdown(report), encoding="utf-8")
    (output / "accuracy.json").write_text(vehicle.report_json(report), encoding="utf-8")
    print(f"wrote {output / 'accuracy.md'} and accuracy.json in {report['runtime_s']:.0f} s", file=sys.stderr)
    for target in report["targets"]:
        print(f"{target.status:8} {target.name}: {target.detail}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
