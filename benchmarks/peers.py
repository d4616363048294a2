"""Adapters that run the peer libraries a user would pick instead of magfit, and express each result
as a :class:`magfit.Calibration` so that every method is scored by the same code.

Every peer has its own convention, read from its documentation and source (versions pinned in
``setup_peers.sh``). In magfit's terms, ``corrected = matrix @ (raw - offset)`` (column vectors):

``magyc`` 1.0.0 (``magyc.ellipsoid_fit``, ``magyc.ellipsoid_fit_fang``, ``magyc.twostep_hsi``)
    Documented as ``calibrated = inv(soft_iron) @ (m - hard_iron)`` with column vectors: ``soft_iron``
    distorts, its inverse corrects, the offset is subtracted. magyc applies it to an (N, 3) array as
    ``magnetic_field.reshape(3, -1)``, which scrambles the axes; we ignore its ``calibrated`` output
    and apply the returned ``(hard_iron, soft_iron)`` ourselves, row by row. ``twostep_hsi`` needs the
    reference field vector and the noise standard deviation: we give it the true ones (an advantage
    no other method gets). ``twostep_hi`` is not run: in 1.0.0 its first step centres the constant
    reference field instead of the measurements, so its information matrix is zero and it always
    raises ``LinAlgError: Singular matrix``.
``magcal`` 1.0.1 (``MagnetometerCalibrator.calibrate("ellipsoid")``)
    ``calibrated = transform_matrix @ (raw - center)`` (its ``apply_calibration``): column vectors,
    offset subtracted, correcting matrix, onto the unit sphere. Its ``center`` is the sample mean (the
    quadric has no linear terms) and it refuses fewer than 500 samples.
``circuitpython-mag-cal`` 1.4.1 (``mag_cal.sensor.Sensor.fit_ellipsoid``)
    ``Sensor.apply``: ``(raw - centre) @ transform`` with row vectors, offset subtracted, correcting
    matrix, onto the unit sphere. ``transform`` is symmetric, so row and column forms agree; we
    still transpose it as its row-vector convention requires.

A peer that is not installed, raises, or returns a non-ellipsoid (NaN, complex or reflecting
matrix) is reported by :class:`PeerFailure` with the reason; the benchmark records it in its table.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import io
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

import magfit

__all__ = ["PEERS", "Peer", "PeerContext", "PeerFailure", "calibration_from_correction", "peer_versions"]


class PeerFailure(Exception):
    """A peer could not produce a calibration; the message says why (shown in the results table)."""


@dataclass(frozen=True)
class PeerContext:
    """What some peers need besides the samples.

    Attributes
    ----------
    field_vector : ndarray, shape (3,)
        The local earth field in the level frame, input units (TWOSTEP's reference field).
    noise : float
        Standard deviation of the sensor noise per axis, input units (TWOSTEP's ``measurement_noise_std``).
    """

    field_vector: NDArray[np.float64]
    noise: float


@dataclass(frozen=True)
class Peer:
    """A peer method: the PyPI distribution it comes from and the adapter that runs it."""

    name: str
    distribution: str
    run: Callable[[NDArray[np.float64], PeerContext | None], magfit.Calibration]
    needs_context: bool = False


def calibration_from_correction(
    name: str,
    offset: NDArray[np.floating],
    correction: NDArray[np.floating],
    radius: float | None,
    samples: NDArray[np.float64],
) -> magfit.Calibration:
    """Express ``corrected = correction @ (raw - offset)``, on a sphere of ``radius``, in magfit's form.

    Parameters
    ----------
    name : str
        Method name recorded in the calibration.
    offset : ndarray, shape (3,)
        Hard-iron offset, input units (subtracted).
    correction : ndarray, shape (3, 3)
        Correcting matrix acting on column vectors, any scale.
    radius : float or None
        Radius of the sphere the peer maps onto, in the corrected units. ``None`` when the peer states
        none: the median norm of the corrected fitting ``samples`` is used (it affects only the mean of
        the sphere distances, never heading, offset or shape errors).
    samples : ndarray, shape (N, 3)
        The samples the peer was fitted to.

    Raises
    ------
    PeerFailure
        The result is not a real, orientation-preserving correction (NaN, complex parts, det <= 0).
    """
    offset = np.asarray(offset)
    correction = np.asarray(correction)
    for label, value in (("offset", offset), ("soft-iron matrix", correction)):
        if np.iscomplexobj(value):
            if np.max(np.abs(value.imag)) > 1e-9 * max(1.0, float(np.max(np.abs(value.real)))):
                raise PeerFailure(f"returned a complex {label} (the fitted quadric is not an ellipsoid)")
            value = value.real
        if not np.all(np.isfinite(value)):
            raise PeerFailure(f"returned NaN/inf in its {label} (the fitted quadric is not an ellipsoid)")
    offset = np.real(offset).astype(np.float64).reshape(3)
    correction = np.real(correction).astype(np.float64).reshape(3, 3)
    determinant = float(np.linalg.det(correction))
    if not determinant > 0:
        symmetric = np.allclose(correction, correction.T, rtol=1e-9, atol=1e-12 * np.abs(correction).max())
        if symmetric and np.all(np.linalg.eigvalsh(correction) < 0):
            # The quadric's sign was not normalised: applied as documented, every corrected vector
            # points backwards (a 180° heading error).
            raise PeerFailure("returned a negative-definite soft-iron matrix: the corrected field points backwards")
        raise PeerFailure(f"returned a soft-iron matrix with det = {determinant:.3g} <= 0 (not an ellipsoid)")
    if radius is None:
        radius = float(np.median(np.linalg.norm((samples - offset) @ correction.T, axis=1)))
    if not (np.isfinite(radius) and radius > 0):
        raise PeerFailure(f"its corrected field has no positive radius ({radius})")
    # magfit scales the matrix to det = 1; the sphere's radius scales with it.
    scale = determinant ** (1.0 / 3.0)
    return magfit.Calibration(name, offset, correction / scale, radius / scale, n_samples=len(samples))


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence the prints and warnings of a peer (magcal prints a report, magyc warns on every fit)."""
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        yield


def _import(module: str, distribution: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise PeerFailure(f"{distribution} is not installed ({error}); run benchmarks/setup_peers.sh") from None


def _magyc_fit(function: str) -> Callable[[NDArray[np.float64], PeerContext | None], magfit.Calibration]:
    def run(samples: NDArray[np.float64], context: PeerContext | None) -> magfit.Calibration:
        magyc = _import("magyc", "magyc")
        with _quiet(), np.errstate(all="ignore"):
            hard_iron, soft_iron, _scrambled = getattr(magyc, function)(samples.copy())
        # Documented convention: calibrated = inv(soft_iron) @ (m - hard_iron); applied per row by us.
        try:
            correction = np.linalg.inv(np.real_if_close(soft_iron))
        except np.linalg.LinAlgError:
            raise PeerFailure("returned a singular soft-iron matrix") from None
        return calibration_from_correction(f"magyc.{function}", hard_iron, correction, None, samples)

    return run


def _magyc_twostep(samples: NDArray[np.float64], context: PeerContext | None) -> magfit.Calibration:
    magyc = _import("magyc", "magyc")
    if context is None:
        raise PeerFailure("TWOSTEP needs the reference field and the noise level (not known for real data)")
    with _quiet(), np.errstate(all="ignore"):
        hard_iron, soft_iron, _scrambled = magyc.twostep_hsi(
            samples.copy(), context.field_vector.copy(), measurement_noise_std=float(context.noise)
        )
    try:
        correction = np.linalg.inv(soft_iron)
    except np.linalg.LinAlgError:
        raise PeerFailure("returned a singular soft-iron matrix") from None
    # Its corrected field has the reference field's magnitude.
    radius = float(np.linalg.norm(context.field_vector))
    return calibration_from_correction("magyc.twostep_hsi", hard_iron, correction, radius, samples)


def _magcal(samples: NDArray[np.float64], context: PeerContext | None) -> magfit.Calibration:
    module = _import("magcal", "magcal")
    calibrator = module.MagnetometerCalibrator()
    calibrator.raw_data = samples.tolist()
    with _quiet(), np.errstate(all="ignore"):
        params = calibrator.calibrate("ellipsoid")
    # apply_calibration: transform_matrix @ (reading - center), unit sphere.
    return calibration_from_correction("magcal.ellipsoid", params["center"], params["transform_matrix"], 1.0, samples)


def _mag_cal(samples: NDArray[np.float64], context: PeerContext | None) -> magfit.Calibration:
    sensor_module = _import("mag_cal.sensor", "circuitpython-mag-cal")
    sensor = sensor_module.Sensor("+X+Y+Z")
    with _quiet(), np.errstate(all="ignore"):
        sensor.fit_ellipsoid(samples.copy())
    # Sensor.apply: (raw - centre) @ transform (row vectors) == transform.T @ (raw - centre); unit sphere.
    return calibration_from_correction("mag_cal.ellipsoid", sensor.centre, np.asarray(sensor.transform).T, 1.0, samples)


#: The peers, in table order.
PEERS: dict[str, Peer] = {
    peer.name: peer
    for peer in (
        Peer("magyc.ellipsoid_fit", "magyc", _magyc_fit("ellipsoid_fit")),
        Peer("magyc.ellipsoid_fit_fang", "magyc", _magyc_fit("ellipsoid_fit_fang")),
        Peer("magyc.twostep_hsi", "magyc", _magyc_twostep, needs_context=True),
        Peer("magcal.ellipsoid", "magcal", _magcal),
        Peer("mag_cal.ellipsoid", "circuitpython-mag-cal", _mag_cal),
    )
}


def peer_versions() -> dict[str, str]:
    """Installed version of each peer distribution (``"not installed"`` when absent)."""
    versions = {}
    for distribution in sorted({peer.distribution for peer in PEERS.values()}):
        try:
            versions[distribution] = importlib.metadata.version(distribution)
        except importlib.metadata.PackageNotFoundError:
            versions[distribution] = "not installed"
    return versions
