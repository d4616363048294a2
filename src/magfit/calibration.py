"""The result of every fit: a hard-iron offset, a soft-iron correction matrix and a field strength.

The measurement model (paper, eq. 1) is ``B_p = W R B e + V``: the true field ``B e`` rotated into the
sensor frame by ``R``, distorted by the soft-iron matrix ``W`` and shifted by the hard-iron offset ``V``.
A :class:`Calibration` undoes it with one convention, used everywhere in magfit::

    corrected = matrix @ (raw - offset)          # lies on a sphere of radius field_strength

``offset`` is V, ``matrix`` is a (scaled) W⁻¹ and ``field_strength`` is B, all in the input units.

Two kinds of calibration share that formula, told apart by :attr:`Calibration.frame`:

- ``"sensor"`` (every magnitude-only fit): the corrected field is in the magnetometer's own axes. Only the
  ellipsoid is determined, so the matrix is one root of A (below) and any root is as good.
- ``"vehicle"`` (a fit against a reference field, ``method="vector"``): the matrix is a general 3x3 that
  also rotates the magnetometer's axes into the vehicle's (soft iron times misalignment). It is not
  symmetric and may be a mirror (a sensor with left-handed axes); an export must carry the rotation or
  refuse.

Only ``A = matrixᵀ matrix / field_strength²`` (paper, eq. 2) is identifiable from the samples: the
samples fix the ellipsoid ``(x − V)ᵀ A (x − V) = 1`` and nothing distinguishes W from W·Q for a
rotation Q. magfit picks the symmetric square root (or, on request, the Cholesky factor) and scales
it so that ``det(matrix) = 1``: the correction then neither shrinks nor grows the field on average,
and ``field_strength`` is the geometric mean of the ellipsoid's semi-axes.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DataFileError, MagfitError, SampleError
from .facts import (
    MODEL_KINDS,
    AutoChoice,
    GyroFacts,
    KnownField,
    LogCompass,
    ModelKind,
    Rejected,
    SampleSource,
    SolverStatus,
    VectorFacts,
    split_details,
)
from .findings import Support
from .motorterm import MotorTerm
from .remedy import option

if TYPE_CHECKING:
    from .findings import Diagnostics

__all__ = ["CONVENTION", "FRAMES", "SCHEMA_VERSION", "Calibration", "Frame"]

#: The formula every exported calibration states, word for word.
CONVENTION = "corrected = matrix @ (raw - offset)"
#: Field strengths a calibration can hold: 1/field_strength² (in A of eq. 2) stays a normal float64.
FIELD_STRENGTH_RANGE = (1e-150, 1e150)
#: The singular values a saved calibration's matrix may have. magfit scales the matrix to |det| = 1, so they
#: bracket 1; a matrix outside stretches one direction a million times more than another (a triangular
#: matrix with a 1e20 entry has det 1): no soft iron does, and its products with the samples (apply, the
#: exports' inverses) leave float64 or are singular in it.
MATRIX_SINGULAR_RANGE = (1e-3, 1e3)
#: Largest offset component a saved calibration may have: the samples' own bound
#: (:data:`magfit._validation.MAX_MAGNITUDE`), so that raw - offset stays finite.
MAX_OFFSET = 1e150
#: What the corrected field's axes are: the magnetometer's own, or the vehicle's (see the module docstring).
Frame = Literal["sensor", "vehicle"]
FRAMES: tuple[Frame, ...] = ("sensor", "vehicle")
#: Version of the JSON layout written by :meth:`Calibration.to_dict`. Version 2 writes the typed facts
#: (``support``, ``model``, ``options``, ``known_field``, ``rejected``, ``solver``, ``auto``, ``vector``,
#: ``gyro``, ``sensor``, ``source``) beside ``details``; version 1 kept them in ``details`` and is still read
#: (:func:`split_details`), as are version-2 files that still keep ``sensor`` and ``source`` there.
SCHEMA_VERSION = 2
#: The versions :meth:`Calibration.from_dict` reads.
READABLE_VERSIONS = (1, 2)
#: The typed facts written to the JSON, in order, with their record types (``options`` is a plain object).
_TYPED: dict[str, Any] = {
    "known_field": KnownField,
    "rejected": Rejected,
    "solver": SolverStatus,
    "auto": AutoChoice,
    "vector": VectorFacts,
    "gyro": GyroFacts,
    "sensor": LogCompass,
    "source": SampleSource,
}
_SCHEMA_NAME = "magfit.calibration"


def _frozen_array(values: ArrayLike, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    array = np.array(values, dtype=np.float64)
    if array.shape != shape:
        raise SampleError(f"Calibration.{name} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise SampleError(f"Calibration.{name} contains NaN or inf: {array.tolist()}")
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class Calibration:
    """A magnetometer calibration: ``corrected = matrix @ (raw - offset)``.

    Parameters
    ----------
    method : str
        The method that produced it (``"ellipsoid"``, ``"sphere"``, ``"minmax"``, ... or ``"identity"``).
    offset : array_like, shape (3,)
        Hard-iron offset V, in input units (µT, gauss, raw counts ...).
    matrix : array_like, shape (3, 3)
        Soft-iron correction, dimensionless. Maps the offset-free samples onto a sphere.
    field_strength : float
        Radius B of that sphere, in input units: the fitted magnitude of the local field.
    unit : str or None
        Name of the input unit, when known (``"uT"``, ``"counts"``, ...). Informational.
    n_samples : int or None
        Number of samples the fit used.
    details : mapping
        Free-form, JSON-serialisable extras of the method (its diagnostics report, intermediate figures).
        Read-only. Keys of schema version 1 that name a typed fact below (``"support"``, ``"options"``,
        ``"rejected"``, ...) are read into that field and leave ``details`` (:func:`magfit.facts.split_details`).
    frame : {"sensor", "vehicle"}
        ``"sensor"``: the matrix corrects within the magnetometer's axes (magnitude-only fits; any root
        of the ellipsoid matrix will do). ``"vehicle"``: the matrix is general and also rotates into the
        vehicle's axes (fits against a reference field); its determinant may be negative.
    motor : MotorTerm or None
        The motors' field ``k c(t − τ)`` (:mod:`magfit.motorterm`), removed from the raw samples before the
        offset: ``corrected = matrix @ (raw − offset − k c)``. None: no term (every calibration without one).
    support : Support or None
        The verdict: supported, weak or refused (forced), each reason with its code. None: not judged
        (a method's bare result, before :func:`magfit.fit` reaches the verdict).
    model : {"sphere", "diag", "full", "vehicle"} or None
        The model family fitted (:data:`magfit.facts.MODEL_KINDS`); None: not said (a calibration made by hand).
    options : mapping
        The options the method ran with, every one (the caller's and the defaults), as JSON holds them.
    known_field : KnownField or None
        The field strength was given (``field_strength=``): the fitted radius, and whether the fit pinned it.
    rejected : Rejected or None
        The samples an outlier-robust fit left out.
    solver : SolverStatus or None
        How an iterative method's solver ended.
    auto, vector, gyro : AutoChoice, VectorFacts, GyroFacts or None
        The facts of that method family: auto's choice, the reference fit's lag and alignment, the gyro-aided
        fit's axis mapping and bias.
    sensor : LogCompass or None
        The compass of a flight log or bag it was fitted on: its id, the firmware's slot and device id (what
        an export writes it for), a rotation already applied to the samples, a calibration they still carry.
    source : SampleSource or None
        Where the samples came from: the file and, for a samples file, the columns fitted (``magfit apply``
        reads the same columns of another file).
    """

    method: str
    offset: NDArray[np.float64]
    matrix: NDArray[np.float64]
    field_strength: float
    unit: str | None = None
    n_samples: int | None = None
    details: Mapping[str, Any] = field(default_factory=dict)
    frame: Frame = "sensor"
    motor: MotorTerm | None = None
    support: Support | None = None
    model: ModelKind | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    known_field: KnownField | None = None
    rejected: Rejected | None = None
    solver: SolverStatus | None = None
    auto: AutoChoice | None = None
    vector: VectorFacts | None = None
    gyro: GyroFacts | None = None
    sensor: LogCompass | None = None
    source: SampleSource | None = None

    def __post_init__(self) -> None:
        if self.motor is not None and not isinstance(self.motor, MotorTerm):
            raise SampleError(f"Calibration.motor must be a MotorTerm or None, got {type(self.motor).__name__}")
        if self.frame not in FRAMES:
            raise SampleError(f"Calibration.frame must be one of {', '.join(FRAMES)}; got {self.frame!r}")
        object.__setattr__(self, "offset", _frozen_array(self.offset, (3,), "offset"))
        object.__setattr__(self, "matrix", _frozen_array(self.matrix, (3, 3), "matrix"))
        strength = float(self.field_strength)
        if not np.isfinite(strength) or strength <= 0:
            raise SampleError(f"Calibration.field_strength must be a positive number, got {strength}")
        low, high = FIELD_STRENGTH_RANGE
        if not low <= strength <= high:  # A = matrixᵀ matrix / field_strength² would under- or overflow
            raise SampleError(
                f"Calibration.field_strength must lie between {low:g} and {high:g} (input units), got {strength:g}; "
                "rescale the samples"
            )
        object.__setattr__(self, "field_strength", strength)
        with np.errstate(all="ignore"):  # entries near 1e300: the determinant overflows, refused below
            determinant = np.linalg.det(self.matrix)
        if not np.isfinite(determinant) or abs(determinant) < 1e-12:
            what = "singular" if np.isfinite(determinant) else "too large (its determinant overflows float64)"
            raise SampleError(f"Calibration.matrix is {what}: it cannot be a soft-iron correction")
        if determinant < 0 and self.frame == "sensor":
            raise SampleError(
                "Calibration.matrix is a mirror (negative determinant): a correction within the sensor's own axes "
                "never is; a mirror belongs to frame='vehicle' (a sensor with left-handed axes)"
            )
        # A details key that names a typed fact (schema 1, or a method that still writes it) is read into it.
        facts, rest = split_details(self.details)
        for name, value in facts.items():
            if name == "options" and self.options:
                continue
            if name != "options" and getattr(self, name) is not None:
                continue
            object.__setattr__(self, name, value)
        if self.model is None and self.frame == "vehicle":
            object.__setattr__(self, "model", "vehicle")
        if self.model is not None and self.model not in MODEL_KINDS:
            raise SampleError(f"Calibration.model must be one of {', '.join(MODEL_KINDS)} or None; got {self.model!r}")
        if self.support is not None and not isinstance(self.support, Support):
            raise SampleError(f"Calibration.support must be a Support or None, got {type(self.support).__name__}")
        for name, kind in _TYPED.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise SampleError(f"Calibration.{name} must be a {kind.__name__} or None, got {type(value).__name__}")
        # Stored as plain JSON types so that a JSON round trip gives back an equal calibration.
        object.__setattr__(self, "details", MappingProxyType(_jsonable(rest)))
        object.__setattr__(self, "options", MappingProxyType(_jsonable(dict(self.options))))

    # ------------------------------------------------------------------ construction

    @classmethod
    def identity(cls, field_strength: float = 1.0, unit: str | None = None) -> Calibration:
        """The calibration that changes nothing: zero offset, identity matrix."""
        return cls("identity", np.zeros(3), np.eye(3), field_strength, unit=unit)

    def with_unit(self, unit: str | None) -> Calibration:
        """The same calibration labelled with another unit name (values unchanged)."""
        return replace(self, unit=unit)

    # ------------------------------------------------------------------ use

    def apply(
        self, raw: ArrayLike, normalized: bool = False, *, regressor: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Correct raw samples: ``matrix @ (raw - offset)`` (paper, eq. 5); with a motor term
        ``matrix @ (raw - offset - k c)`` (docs/methods.md, eq. M1).

        Parameters
        ----------
        raw : array_like, shape (N, 3) or (3,)
            Raw samples, one per row, in input units.
        normalized : bool
            If true, divide by ``field_strength``: the corrected samples then lie on the unit sphere
            (the space the paper evaluates in).
        regressor : array_like, shape (N,) or scalar, optional
            The motors' regressor at each sample (amperes or throttle, :attr:`motor`'s, already at its lag).
            Required when the calibration holds a motor term, refused when it holds none.

        Returns
        -------
        ndarray, same shape as ``raw``
            Corrected samples, in input units (or dimensionless when ``normalized``).
        """
        array = np.asarray(raw, dtype=np.float64)
        if array.shape != (3,) and (array.ndim != 2 or array.shape[1] != 3):
            raise SampleError(
                f"apply() takes samples of shape (N, 3) or (3,), got shape {array.shape}; rows are samples (x, y, z)"
            )
        offset_free = array - self.offset
        if self.motor is not None or regressor is not None:
            offset_free = offset_free - self._motor_field(array, regressor)
        # One matrix-vector product per output axis: NumPy's (N, 3) @ (3, 3) goes through a BLAS gemm that
        # is 10-60x slower on such tall, three-column arrays (worst when BLAS threads compete for cores).
        corrected = np.empty_like(offset_free)
        for axis in range(3):
            corrected[..., axis] = offset_free @ self.matrix[axis]
        if normalized:
            corrected = corrected / self.field_strength
        return corrected

    def _motor_field(self, array: NDArray[np.float64], regressor: ArrayLike | None) -> NDArray[np.float64]:
        if self.motor is None:
            raise SampleError("apply(regressor=...) given to a calibration without a motor term")
        if regressor is None:
            raise SampleError(
                f"this calibration holds the motors' field (the {self.motor.regressor}): correcting a sample needs the "
                f"{self.motor.regressor} at that sample (Calibration.apply(raw, regressor=...) in Python); for a "
                f"calibration without the term, calibrate again with {option('motor', 'none')}",
                remedy=(("motor", "none"),),
            )
        values = np.asarray(regressor, dtype=np.float64)
        expected = array.shape[:-1]
        if values.shape != expected and values.shape != ():
            raise SampleError(f"apply(): regressor must have shape {expected}, got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise SampleError("apply(): the regressor holds NaN or inf")
        return self.motor.field(np.broadcast_to(values, expected))

    @property
    def is_symmetric(self) -> bool:
        """True when the matrix equals its transpose (to 1e-9 of its largest entry)."""
        scale = float(np.max(np.abs(self.matrix)))
        return bool(np.max(np.abs(self.matrix - self.matrix.T)) <= 1e-9 * scale)

    # ------------------------------------------------------------------ diagnostics

    @property
    def diagnostics(self) -> Diagnostics | None:
        """The typed :class:`~magfit.Diagnostics` that :func:`magfit.fit` attached, or None."""
        stored = self.details.get("diagnostics")
        if stored is None:
            return None
        from .findings import Diagnostics

        return Diagnostics.from_dict(stored)

    # ------------------------------------------------------------------ the fitted ellipsoid

    @property
    def ellipsoid_matrix(self) -> NDArray[np.float64]:
        """A of eq. (2) scaled to the unit sphere: ``(x − offset)ᵀ A (x − offset) = 1`` on the ellipsoid."""
        unit_map = self.matrix / self.field_strength
        return unit_map.T @ unit_map

    @property
    def semi_axes(self) -> NDArray[np.float64]:
        """Semi-axis lengths of the fitted ellipsoid, shape (3,), input units.

        Entry i belongs to the semi-axis whose direction is closest to sensor axis i (x, y, z), so the
        values read like the paper's table.
        """
        return self._ellipsoid_axes()[0]

    @property
    def axes(self) -> NDArray[np.float64]:
        """Unit directions of the semi-axes, shape (3, 3): column i goes with ``semi_axes[i]``."""
        return self._ellipsoid_axes()[1]

    def _ellipsoid_axes(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        eigenvalues, eigenvectors = np.linalg.eigh(self.ellipsoid_matrix)
        # Assign eigenvector j to the sensor axis it is most aligned with (best of the 6 permutations).
        best = max(
            itertools.permutations(range(3)),
            key=lambda perm: sum(abs(eigenvectors[axis, vec]) for axis, vec in enumerate(perm)),
        )
        order = list(best)
        lengths = 1.0 / np.sqrt(eigenvalues[order])
        directions = eigenvectors[:, order]
        directions = directions * np.sign(np.diag(directions) + (np.diag(directions) == 0))
        lengths.flags.writeable = False
        directions.flags.writeable = False
        return lengths, directions

    # ------------------------------------------------------------------ comparison

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Calibration):
            return NotImplemented
        return (
            self.method == other.method
            and np.array_equal(self.offset, other.offset)
            and np.array_equal(self.matrix, other.matrix)
            and self.field_strength == other.field_strength
            and self.unit == other.unit
            and self.n_samples == other.n_samples
            and dict(self.details) == dict(other.details)
            and self.frame == other.frame
            and self.motor == other.motor
            and _facts(self) == _facts(other)
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        frame = ", frame='vehicle'" if self.frame == "vehicle" else ""
        if self.motor is not None:  # the motors' field: its regressor and coefficients
            frame += f", motor={self.motor.regressor}:{np.array2string(self.motor.coefficients, precision=5)}"
        return (
            f"Calibration(method={self.method!r}{frame}, offset={np.array2string(self.offset, precision=5)}{unit}, "
            f"field_strength={self.field_strength:.6g}{unit}, "
            f"matrix={np.array2string(self.matrix, precision=5, separator=', ')})"
        )

    # ------------------------------------------------------------------ serialisation

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict; floats are kept exactly (JSON writes the shortest round-trip repr)."""
        return {
            "schema": _SCHEMA_NAME,
            "schema_version": SCHEMA_VERSION,
            "convention": CONVENTION,
            "method": self.method,
            "unit": self.unit,
            "offset": self.offset.tolist(),
            "matrix": self.matrix.tolist(),
            "field_strength": self.field_strength,
            "n_samples": self.n_samples,
            "frame": self.frame,
            "details": _jsonable(dict(self.details)),
            **({"motor": self.motor.to_dict()} if self.motor is not None else {}),
            **_facts(self),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Calibration:
        """Inverse of :meth:`to_dict`; checks the schema, the convention and every field.

        Raises
        ------
        DataFileError
            Anything that is not a usable calibration: another schema or version, a missing field, a
            value of the wrong type (strings for numbers, a ragged matrix, ``details`` that is not an
            object), a mirror (negative determinant) or singular matrix, a matrix whose singular values
            leave ``MATRIX_SINGULAR_RANGE`` (1e-3 to 1e3), an offset beyond ``MAX_OFFSET``, a field strength
            outside ``FIELD_STRENGTH_RANGE`` (1e-150 to 1e150), a number in ``details`` beyond float64,
            malformed ``details.diagnostics``.
        """
        if not isinstance(data, Mapping):
            raise DataFileError(f"a calibration must be a JSON object, got {type(data).__name__}")
        if data.get("schema") != _SCHEMA_NAME:
            raise DataFileError(
                f"not a magfit calibration (schema is {_shown(data.get('schema'))}, expected {_SCHEMA_NAME!r})"
            )
        version = data.get("schema_version")
        if not _is_int(version) or version not in READABLE_VERSIONS:
            raise DataFileError(
                f"calibration schema version {_shown(version)} is not supported (this magfit reads "
                f"{' and '.join(map(str, READABLE_VERSIONS))}); upgrade magfit or re-run the calibration"
            )
        if data.get("convention") != CONVENTION:
            raise DataFileError(f"calibration convention {_shown(data.get('convention'))} is not {CONVENTION!r}")
        missing = [name for name in ("method", "offset", "matrix", "field_strength") if name not in data]
        if missing:
            raise DataFileError(f"calibration file lacks the field {missing[0]!r}")
        method, unit, n_samples = data["method"], data.get("unit"), data.get("n_samples")
        if not isinstance(method, str) or not method:
            raise DataFileError(f"calibration 'method' must be a name, got {_shown(method)}")
        if unit is not None and not isinstance(unit, str):
            raise DataFileError(f"calibration 'unit' must be a string or null, got {_shown(unit)}")
        if n_samples is not None and (not _is_int(n_samples) or n_samples < 0):
            raise DataFileError(f"calibration 'n_samples' must be a count or null, got {_shown(n_samples)}")
        details = data.get("details")
        if details is None:
            details = {}
        if not isinstance(details, Mapping):
            raise DataFileError(f"calibration 'details' must be an object, got {type(details).__name__}")
        diagnostics = details.get("diagnostics")
        if diagnostics is not None and not isinstance(diagnostics, Mapping):
            raise DataFileError(
                f"calibration 'details.diagnostics' must be an object, got {type(diagnostics).__name__}"
            )
        offset = np.array([_number(v, f"offset[{i}]") for i, v in enumerate(_items(data["offset"], 3, "offset"))])
        rows = _items(data["matrix"], 3, "matrix")
        matrix = np.array(
            [[_number(v, f"matrix[{i}][{j}]") for j, v in enumerate(_items(row, 3, f"matrix[{i}]"))]
             for i, row in enumerate(rows)]
        )  # fmt: skip
        field_strength = _number(data["field_strength"], "field_strength")
        frame = data.get("frame", "sensor")  # files written before frames existed are all "sensor"
        if frame not in FRAMES:
            raise DataFileError(f"calibration 'frame' must be one of {', '.join(FRAMES)}; got {_shown(frame)}")
        with np.errstate(all="ignore"):  # a determinant beyond float64 is refused by the constructor
            determinant = float(np.linalg.det(matrix))
        if frame == "vehicle" and determinant < 0:
            determinant = -determinant  # a left-handed sensor's alignment: a mirror is allowed here
        if not determinant > 0:
            what = "a mirror (negative determinant)" if determinant < 0 else "singular"
            raise DataFileError(f"calibration 'matrix' is {what}: no soft-iron correction is; re-run the calibration")
        _check_usable(offset, matrix)
        _check_finite_details(details)
        typed = {name: data[name] for name in ("support", "model", "options", *_TYPED) if data.get(name) is not None}
        for name, value in typed.items():
            _check_finite_details(value, name)
        if version == 1 and typed:
            raise DataFileError(
                f"calibration schema version 1 keeps its facts in 'details', not {', '.join(map(repr, typed))}; "
                "re-run the calibration"
            )
        facts = _read_facts(typed)
        try:
            calibration = cls(
                method=method,
                offset=offset,
                matrix=matrix,
                field_strength=field_strength,
                unit=unit,
                n_samples=n_samples,
                details=details,
                frame=frame,
                motor=MotorTerm.from_dict(data["motor"]) if data.get("motor") is not None else None,
                **facts,
            )
            if diagnostics is not None:
                calibration.diagnostics  # noqa: B018 - read once, so a malformed report fails here, not later
        except MagfitError as error:
            raise DataFileError(f"calibration is not usable: {error}") from None
        except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError) as error:
            where = "'details.diagnostics'" if diagnostics is not None else "one of its facts"
            raise DataFileError(
                f"calibration {where} is malformed ({type(error).__name__}: {error}); "
                "re-run the calibration or delete that entry"
            ) from None
        except RecursionError:
            raise DataFileError("calibration 'details' is nested too deeply to be read") from None
        return calibration

    def to_json(self, indent: int | None = 2) -> str:
        """Serialise to JSON text (lossless; see :meth:`from_json`)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    @classmethod
    def from_json(cls, text: str | bytes) -> Calibration:
        """Read a calibration written by :meth:`to_json`.

        Raises
        ------
        DataFileError
            Not JSON (or JSON with NaN or Infinity, which :meth:`to_json` never writes, or nested too
            deeply), or not a usable calibration (see :meth:`from_dict`).
        """
        if not isinstance(text, (str, bytes, bytearray)):
            raise DataFileError(f"from_json() takes the JSON text, got {type(text).__name__}")
        try:
            data = json.loads(text, parse_constant=_refuse_constant)
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise DataFileError(f"calibration is not valid JSON: {_one_line(str(error))}") from None
        except RecursionError:
            raise DataFileError("calibration is not valid JSON: nested too deeply") from None
        if not isinstance(data, dict):
            raise DataFileError("calibration JSON must be an object")
        return cls.from_dict(data)


def _check_usable(offset: NDArray[np.float64], matrix: NDArray[np.float64]) -> None:
    """Refuse a matrix no soft iron has (singular values outside :data:`MATRIX_SINGULAR_RANGE`) and an offset
    beyond :data:`MAX_OFFSET`: read back, they would correct samples to inf or make an export's inverse fail."""
    low, high = MATRIX_SINGULAR_RANGE
    with np.errstate(all="ignore"):
        try:
            singular = np.linalg.svd(matrix, compute_uv=False)
        except np.linalg.LinAlgError:
            singular = np.array([np.inf])
    if not (np.all(np.isfinite(singular)) and singular.max() <= high and singular.min() >= low):
        stretch = f"{singular.max():.3g} to {singular.min():.3g}" if np.all(np.isfinite(singular)) else "beyond float64"
        raise DataFileError(
            f"calibration 'matrix' is not a usable correction: it scales directions by {stretch}, outside {low:g} to "
            f"{high:g} (magfit writes matrices of determinant 1, whose singular values bracket 1); re-run the "
            "calibration"
        )
    largest = float(np.max(np.abs(offset)))
    if largest > MAX_OFFSET:
        raise DataFileError(
            f"calibration 'offset' holds {largest:.3g}, beyond the {MAX_OFFSET:g} that samples can hold; re-run the "
            "calibration"
        )


def _facts(calibration: Calibration) -> dict[str, Any]:
    """The typed facts as JSON holds them (schema version 2), those that are set."""
    facts: dict[str, Any] = {}
    if calibration.support is not None:
        facts["support"] = calibration.support.to_dict()
    if calibration.model is not None:
        facts["model"] = calibration.model
    if calibration.options:
        facts["options"] = _jsonable(dict(calibration.options))
    for name in _TYPED:
        value = getattr(calibration, name)
        if value is not None:
            facts[name] = _jsonable(value.to_dict())
    return facts


def _read_facts(typed: Mapping[str, Any]) -> dict[str, Any]:
    """The typed facts of a version-2 file (the inverse of :func:`_facts`); raises on a malformed entry."""
    facts: dict[str, Any] = {}
    for name, value in typed.items():
        try:
            facts[name] = _read_fact(name, value)
        except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError) as error:
            raise DataFileError(
                f"calibration {name!r} is malformed ({type(error).__name__}: {error}); re-run the calibration, or "
                f"delete the entry {name!r} from the file to read the rest without it"
            ) from None
    return facts


def _read_fact(name: str, value: Any) -> Any:
    """One typed fact of a version-2 file, from its JSON form."""
    if name == "model":
        if value not in MODEL_KINDS:
            raise ValueError(f"'model' must be one of {', '.join(MODEL_KINDS)}, got {_shown(value)}")
        return value
    if not isinstance(value, Mapping):
        raise TypeError(f"{name!r} must be an object, got {type(value).__name__}")
    if name == "support":
        return Support.from_dict(dict(value))
    if name == "options":
        return dict(value)
    return _TYPED[name].from_dict(value)


def _check_finite_details(details: Any, root: str = "details") -> None:
    """Refuse a number in ``details`` beyond float64 (``1e999`` reads as inf, which :meth:`Calibration.to_json`
    cannot write back), naming where it is."""
    pending: list[tuple[str, Any]] = [(root, details)]
    while pending:
        where, value = pending.pop()
        if isinstance(value, float) and not math.isfinite(value):
            raise DataFileError(
                f"calibration '{where}' is {value}, beyond the range of float64 (JSON has no such number); delete that "
                "entry or re-run the calibration"
            )
        if isinstance(value, Mapping):
            pending.extend((f"{where}.{key}", item) for key, item in value.items())
        elif isinstance(value, (list, tuple)):
            pending.extend((f"{where}[{index}]", item) for index, item in enumerate(value))


def _refuse_constant(name: str) -> float:
    raise DataFileError(f"calibration is not valid JSON: {name} is no number (magfit never writes it)")


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _shown(value: Any) -> str:
    """A short repr for a message (a huge value from a broken file must not flood the terminal)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _items(value: Any, count: int, name: str) -> list[Any]:
    if not isinstance(value, (list, tuple)) or len(value) != count:
        size = f"{len(value)} entries" if isinstance(value, (list, tuple)) else type(value).__name__
        raise DataFileError(f"calibration '{name}' must be a list of {count} entries, got {size}")
    return list(value)


def _number(value: Any, name: str) -> float:
    """A JSON number as a finite float; strings, booleans and numbers beyond float64 are refused."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataFileError(f"calibration '{name}' must be a number, got {_shown(value)}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise DataFileError(f"calibration '{name}' is beyond the range of float64 ({_shown(value)})")
    return number


def _jsonable(value: Any) -> Any:
    """Convert numpy scalars and arrays inside ``details`` to plain JSON types."""
    if isinstance(value, Mapping):
        return {str(key): _jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(item) for item in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value
