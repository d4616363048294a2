"""What the benchmarks share: the heading metric (RMS over level headings against the simulated truth), the mild
random sensor, magfit's verdict on a fit, paired ratios of RMS heading errors, checked targets, the versions line
and the compact JSON of a report.

``accuracy.py`` (the magnitude-only grid), ``accuracy_vehicle.py`` (the vehicle scenarios), ``campaign.py`` and the
tests that score against truth import from here, not from each other.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import json
import platform
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

import magfit

ROOT = Path(__file__).resolve().parent.parent
#: Level headings the heading metric averages over (one per degree).
N_HEADINGS = 360


def best_rotation(fitted_matrix: NDArray[np.float64], true_matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation Q that best turns ``fitted_matrix @ d`` into ``true_matrix @ d`` over all directions.

    Parameters
    ----------
    fitted_matrix, true_matrix : ndarray, shape (3, 3)
        Soft-iron corrections (any positive scale, det > 0).

    Returns
    -------
    ndarray, shape (3, 3)
        ``polar(true_matrix @ inv(fitted_matrix))``: the orthogonal factor of its polar decomposition
        (eq. (P) of the module docstring), a proper rotation.
    """
    left, _, right = np.linalg.svd(true_matrix @ np.linalg.inv(fitted_matrix))
    rotation = left @ right
    if np.linalg.det(rotation) < 0:  # only for a reflecting fit; keep Q a rotation
        left[:, -1] *= -1
        rotation = left @ right
    return rotation


def level_readings(simulation: magfit.Simulation, n_headings: int = N_HEADINGS) -> NDArray[np.float64]:
    """Noise-free raw readings at roll = pitch = 0 and ``n_headings`` yaws 0 … 360°, shape (n_headings, 3)."""
    yaw = np.arange(n_headings) * (360.0 / n_headings)
    attitudes = np.column_stack([np.zeros(n_headings), np.zeros(n_headings), yaw])
    return simulation.distort(attitudes)


def heading_differences_deg(
    offset: NDArray[np.float64],
    matrix: NDArray[np.float64],
    simulation: magfit.Simulation,
    raw: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Heading of ``Q matrix (raw − offset)`` minus that of the true calibration, degrees, in (−180, 180].

    ``Q = best_rotation(matrix, truth.matrix)``; the heading of a level vector is ``atan2(y, x)``.
    """
    rotation = best_rotation(matrix, simulation.truth.matrix)
    fitted = (raw - offset) @ (rotation @ matrix).T
    true = simulation.truth.apply(raw)
    difference = np.degrees(np.arctan2(fitted[:, 1], fitted[:, 0]) - np.arctan2(true[:, 1], true[:, 0]))
    return (difference + 180.0) % 360.0 - 180.0


def heading_error_deg(
    calibration: magfit.Calibration, simulation: magfit.Simulation, n_headings: int = N_HEADINGS
) -> float:
    """Calibration heading error: RMS over level headings of the heading difference, degrees (see module doc)."""
    raw = level_readings(simulation, n_headings)
    differences = heading_differences_deg(calibration.offset, calibration.matrix, simulation, raw)
    return float(np.sqrt(np.mean(differences**2)))


def mild_distortion(rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A random mild sensor, (W, V): scales within ±2 %, cross terms within ±1 %, hard iron U(−0.4, 0.4)·B.

    W is symmetric (a soft iron has no rotation of its own that a calibration could see), B = 1.
    """
    cross = rng.uniform(-0.01, 0.01, 3)
    soft_iron = np.diag(1.0 + rng.uniform(-0.02, 0.02, 3))
    soft_iron[[0, 0, 1], [1, 2, 2]] = cross
    soft_iron[[1, 2, 2], [0, 0, 1]] = cross
    return soft_iron, rng.uniform(-0.4, 0.4, 3)


def verdict_of(calibration: magfit.Calibration | None, error: str) -> tuple[str | None, str | None]:
    """(verdict, its first reason) of a magfit fit, from ``calibration.support`` or a refusal's message.

    A forced fit keeps the verdict "refused" (with ``forced``); a ``CalibrationError`` of an unforced fit
    is a refusal too. A peer's calibration carries no verdict: (None, None).
    """
    if calibration is None:
        if error.startswith("CalibrationError"):
            return "refused", error.removeprefix("CalibrationError: ")
        return None, None
    support = calibration.support
    if support is None:
        return None, None
    reasons = [*support.refusals, *support.weaknesses]
    return support.verdict, (str(reasons[0]) if reasons else None)


def failure_message(error: BaseException) -> str:
    """``Type: first line of the message``: how a failed fit is recorded (a result, with its reason)."""
    message = str(error).strip().splitlines()[0] if str(error).strip() else ""
    # A refusal is a CalibrationError whatever its subclass (auto's UndeterminedChoice): a verdict.
    name = "CalibrationError" if isinstance(error, magfit.CalibrationError) else type(error).__name__
    return f"{name}: {message}" if message else name


# ====================================================================== ratios and targets


class Scored(Protocol):
    """One trial's score: its RMS heading error in degrees, None when the method failed on the trial."""

    @property
    def heading_deg(self) -> float | None: ...


@dataclass(frozen=True)
class Ratio:
    """A ratio of RMS heading errors with its standard error (delta method), on ``pairs`` trials."""

    value: float
    se: float
    pairs: int

    def __str__(self) -> str:
        return f"{self.value:.3f} ± {self.se:.3f}"


def paired_ratio(numerator: Sequence[Scored], denominator: Sequence[Scored]) -> Ratio | None:
    """RMS heading error of ``numerator`` over that of ``denominator``, on the trials both fitted.

    The trials are paired (same samples), so the standard error comes from the per-trial differences
    ``a²/mean(a²) − b²/mean(b²)``: ``se(log R) ≈ ½ sd(·) / √n``.
    """
    pairs = np.array(
        [
            (a.heading_deg, b.heading_deg)
            for a, b in zip(numerator, denominator, strict=True)
            if a.heading_deg is not None and b.heading_deg is not None
        ]
    )
    if len(pairs) == 0:
        return None
    squares = pairs**2
    means = squares.mean(axis=0)
    if not means[1] > 0:
        return None
    value = float(np.sqrt(means[0] / means[1]))
    spread = np.std(squares[:, 0] / means[0] - squares[:, 1] / means[1], ddof=1) if len(pairs) > 1 else np.nan
    return Ratio(value, float(value * 0.5 * spread / np.sqrt(len(pairs))), len(pairs))


@dataclass
class Target:
    """One checked target: PASS, FAIL or NOT RUN, with the numbers behind it."""

    name: str
    status: str
    detail: str
    items: list[str] = field(default_factory=list)


def pass_fail(ok: bool) -> str:
    """A target's status when it ran: PASS or FAIL."""
    return "PASS" if ok else "FAIL"


def note(notes: dict[str, int], message: str) -> int:
    """The number of ``message`` among a table's footnotes (added at the end when new)."""
    if message not in notes:
        notes[message] = len(notes) + 1
    return notes[message]


# ====================================================================== the report


def versions(peers: bool) -> dict[str, str]:
    """Python, numpy, scipy, magfit (with its git commit) and the peers' versions."""
    found = {"python": platform.python_version(), "numpy": np.__version__}
    for name in ("scipy",):
        found[name] = importlib.metadata.version(name)
    commit = "unknown"
    try:
        commit = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    found["magfit"] = f"{magfit.__version__} (commit {commit})"
    if peers:
        from peers import peer_versions  # the sibling module; imported here so that magfit-only runs need no peer

        found.update(peer_versions())
    return found


def report_json(report: Mapping[str, Any]) -> str:
    """Every number of the report as compact JSON (trial-level outcomes included, 6 significant digits).

    Dataclass instances (outcomes, summaries, targets) become their fields.
    """

    def convert(value: Any) -> Any:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return convert(dataclasses.asdict(value))
        if isinstance(value, Mapping):
            return {str(k): convert(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [convert(v) for v in value]
        if isinstance(value, (np.floating, np.integer)):
            return convert(value.item())
        if isinstance(value, float):
            # Six significant digits: far below the trial-to-trial spread, and a file a third the size.
            return float(f"{value:.6g}") if np.isfinite(value) else None
        return value

    return json.dumps(convert(report), separators=(",", ":"), allow_nan=False)


def kept_details(calibration: magfit.Calibration, keys: Sequence[str]) -> dict[str, Any]:
    """The facts named ``keys`` as the results record them (the names of a calibration's schema-1 ``details``),
    read from its typed fields: ``support``, ``chosen``, ``method_used``, ``reason``, ``weak`` (auto's: the
    verdict's weaknesses), ``n_rejected``, ``lag_s``, ``mapping``; any other key from ``details``."""
    facts: dict[str, Any] = dict(calibration.details)
    if calibration.support is not None:
        facts["support"] = calibration.support.to_dict()
    if calibration.auto is not None:
        facts.update(chosen=calibration.auto.chosen, method_used=calibration.auto.method_used,
                     reason=calibration.auto.reason)  # fmt: skip
        if calibration.support is not None:
            facts["weak"] = [str(w) for w in calibration.support.weaknesses]
    if calibration.rejected is not None:
        facts["n_rejected"] = calibration.rejected.count
    if calibration.vector is not None:
        facts["lag_s"] = calibration.vector.lag_s
    if calibration.gyro is not None:
        facts.update(lag_s=calibration.gyro.lag_s, mapping=calibration.gyro.mapping)
    return {key: value for key, value in facts.items() if key in keys}
