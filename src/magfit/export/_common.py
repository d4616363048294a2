"""Helpers shared by the export targets: units, the symmetric matrix, number formatting, header facts."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..calibration import CONVENTION, Calibration
from ..errors import ExportError, OptionError
from ..units import Unit, conversion_factor, get_unit

#: Largest relative asymmetry max|M − Mᵀ| / max|M| still treated as a symmetric matrix (rounding only).
SYMMETRY_TOLERANCE = 1e-9


def version() -> str:
    """magfit's version, written into every export (no date, so the output is reproducible)."""
    from .. import __version__

    return __version__


def plain(text: object) -> str:
    """``text`` as printable ASCII on one line, safe inside any comment (C, MATLAB, shell, params)."""
    ascii_text = "".join(ch if " " <= ch <= "~" else "?" for ch in str(text))
    return ascii_text.replace("*/", "*_/")


def float32_text(value: float) -> str:
    """Shortest text that still round-trips a float32 (9 significant digits, ``%.9g``)."""
    return f"{float(value):.9g}"


def c_float(value: float) -> str:
    """A C ``float`` literal with 9 significant digits (``1`` becomes ``1.0f``, never the invalid ``1f``)."""
    text = float32_text(value)
    if not any(ch in text for ch in ".en"):
        text += ".0"
    return text + "f"


def label_unit(calibration: Calibration, unit: str | None) -> str | None:
    """The unit to print for targets that keep the input unit (no conversion).

    An explicit ``unit`` must be a known unit (:class:`OptionError` otherwise) and is written by its
    canonical name; ``calibration.unit`` is only a label, written canonically when magfit knows it.
    """
    if unit is not None:
        return get_unit(unit).name
    if calibration.unit is None:
        return None
    try:
        return get_unit(calibration.unit).name
    except OptionError:
        return plain(calibration.unit)


def unit_phrase(unit: str | None) -> str:
    """``"uT"`` or a phrase saying that the unit was not recorded."""
    return unit if unit is not None else "the samples' unit (not recorded: pass unit=...)"


def physical_unit(calibration: Calibration, unit: str | None, target: str, target_unit: str) -> Unit:
    """The samples' unit for a target that converts to ``target_unit``; refuses counts and unknown units."""
    if unit is not None:
        resolved = get_unit(unit)  # OptionError for a misspelt explicit unit
    elif calibration.unit is None:
        raise ExportError(
            f"the {target} export needs values in {target_unit}, but the calibration does not record the unit "
            "of its samples; pass unit='uT' (or 'nT', 'mT', 'G', 'mG')"
        )
    else:
        try:
            resolved = get_unit(calibration.unit)
        except OptionError:
            raise ExportError(
                f"the {target} export needs values in {target_unit}, but the calibration's unit "
                f"{calibration.unit!r} is not one magfit knows; pass unit='uT' (or 'nT', 'mT', 'G', 'mG')"
            ) from None
    if not resolved.is_physical:
        raise ExportError(
            f"the {target} export needs values in {target_unit}, but the samples are raw counts of unknown "
            "scale; pass the physical unit of the samples (e.g. unit='uT') or refit on samples in a physical unit"
        )
    return resolved


def factor(source: Unit, target_unit: str) -> float:
    """The exact conversion factor from ``source`` to ``target_unit`` (both physical)."""
    return conversion_factor(source.name, target_unit)


@dataclass(frozen=True)
class SymmetricMatrix:
    """A symmetric soft-iron matrix for targets that store only six numbers, and how it was obtained."""

    matrix: NDArray[np.float64]
    #: Rotation (degrees) between the exported vectors and ``Calibration.apply``; 0 when unchanged.
    rotation_deg: float
    #: A comment line explaining a conversion, or None when the matrix was already symmetric.
    note: str | None


def symmetric_matrix(calibration: Calibration, target: str) -> SymmetricMatrix:
    """The calibration's matrix as the symmetric matrix ArduPilot and PX4 store.

    A symmetric matrix passes through. A Cholesky root (``details["root"] == "cholesky"``) is
    replaced by the symmetric root ``S = sqrtm(Mᵀ M)``: both satisfy ``Mᵀ M = S² = B² A`` (paper,
    eq. 2), so they fit the same ellipsoid and give the same ``|corrected|``; they differ by the
    rotation ``Q = M S⁻¹``, which the samples cannot identify (the rotation is an artefact of the
    factorisation), and the symmetric root is the one that adds no rotation. Any other
    non-symmetric matrix may carry a real axis alignment, which a symmetric matrix would silently
    drop, so it is refused.
    """
    m = calibration.matrix
    asymmetry = float(np.max(np.abs(m - m.T)) / np.max(np.abs(m)))
    if asymmetry <= SYMMETRY_TOLERANCE:
        return SymmetricMatrix(0.5 * (m + m.T), 0.0, None)
    if calibration.details.get("root") != "cholesky" or np.linalg.det(m) <= 0:
        raise ExportError(
            f"the {target} export stores a symmetric soft-iron matrix, but this calibration's matrix is not "
            f"symmetric (max|M - M^T| / max|M| = {asymmetry:.3g}) and may encode an axis rotation that {target} "
            "cannot represent; refit with root='sqrt' or export to 'c', 'fusion', 'magcal' or 'json'"
        )
    eigenvalues, eigenvectors = np.linalg.eigh(m.T @ m)
    root = (eigenvectors * np.sqrt(eigenvalues)) @ eigenvectors.T
    root = 0.5 * (root + root.T)
    rotation = m @ np.linalg.inv(root)  # orthogonal, det +1: M = Q S (polar decomposition)
    angle = math.degrees(math.acos(min(1.0, max(-1.0, (float(np.trace(rotation)) - 1.0) / 2.0))))
    note = (
        "magfit's matrix is a Cholesky root (not symmetric); this file holds the symmetric root "
        f"sqrtm(matrix^T matrix): same ellipsoid and same |corrected|, but the corrected vector is rotated "
        f"by {angle:.3f} deg from magfit's apply() (that rotation is an artefact of the Cholesky factor)"
    )
    return SymmetricMatrix(root, angle, note)


def describe(calibration: Calibration, unit: str | None) -> list[str]:
    """Facts every export states in its header comment (plain ASCII, no date)."""
    root = calibration.details.get("root")
    method = plain(calibration.method) + (f" (root: {plain(root)})" if root else "")
    samples = f"{calibration.n_samples} samples" if calibration.n_samples is not None else "sample count not recorded"
    label = unit if unit is not None else "input units"
    return [
        f"written by magfit {version()}; method: {method}; {samples}",
        f"magfit convention: {CONVENTION}",
        f"field strength (radius of the corrected sphere): {float32_text(calibration.field_strength)} {label}",
    ]
