"""What a calibration knows beyond its numbers: typed, frozen facts that other code reads.

:class:`magfit.Calibration` carries these records as fields (schema version 2): the model family fitted,
the samples rejected as outliers, the solver's status, the known field strength given and fitted, one
record per method family (``auto``'s choice, ``vector``'s lag and alignment, ``gyro``'s axis mapping and
bias), and where the samples came from: the recording and its columns (:class:`SampleSource`, which
``magfit apply`` reads the same columns by) and a log's compass (:class:`LogCompass`, the slot and device id
an export writes for). The verdict is :class:`magfit.findings.Support`. ``details`` keeps free-form extras that no other
code reads.

Schema version 1 kept all of them in ``details`` under fixed keys (and files of schema version 2 written
before :class:`LogCompass` and :class:`SampleSource` existed keep those two under ``details["sensor"]`` and
``details["source"]``); :func:`split_details` reads those keys into the records (an older file, and code
that still writes them), so one reader serves every file.
Every record has ``to_dict`` / ``from_dict`` (plain JSON types; ``from_dict(to_dict(x)) == x``).
"""

from __future__ import annotations

import operator
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, cast

from .findings import Support

__all__ = [
    "MODEL_KINDS",
    "AutoChoice",
    "GyroFacts",
    "KnownField",
    "LogCompass",
    "ModelKind",
    "Rejected",
    "SampleSource",
    "SolverStatus",
    "VectorFacts",
    "split_details",
]

#: The model families: the ellipsoid's structure in the sensor frame (``sphere``: hard iron only; ``diag``:
#: axis-aligned scales; ``full``: a general ellipsoid) or a general 3x3 into the vehicle's axes (``vehicle``).
ModelKind = Literal["sphere", "diag", "full", "vehicle"]
MODEL_KINDS: tuple[ModelKind, ...] = ("sphere", "diag", "full", "vehicle")


def _float_or_none(value: Any) -> float | None:
    return None if value is None else float(value)


def _floats(value: Any) -> tuple[float, ...] | None:
    return None if value is None else tuple(float(v) for v in value)


@dataclass(frozen=True)
class KnownField:
    """A field strength the caller gave (``field_strength=``): the calibration is scaled to it.

    Attributes
    ----------
    fitted : float or None
        The radius the samples alone give, input units (the calibration's ``field_strength`` is the given one).
    pinned : bool
        True when the fit itself held the radius at the given value (only the rest was fitted), not only
        rescaled its result.
    """

    fitted: float | None
    pinned: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {"fitted": self.fitted, "pinned": self.pinned}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> KnownField:
        return cls(fitted=_float_or_none(data.get("fitted")), pinned=bool(data.get("pinned", False)))


@dataclass(frozen=True)
class Rejected:
    """The samples an outlier-robust fit left out, run-length encoded.

    Attributes
    ----------
    count : int
        How many samples were rejected (all of them, even when ``runs`` is truncated).
    runs : tuple of (start, stop)
        Each run stands for ``range(start, stop)`` of the samples fitted.
    truncated : bool
        True when only the first runs are kept (see :data:`magfit.methods.robust.MAX_STORED_RUNS`).
    threshold : float or None
        The rule's threshold in robust standard deviations (``|r − median r| > threshold · σ_MAD``); None:
        the robust method's default.
    """

    count: int
    runs: tuple[tuple[int, int], ...] = ()
    truncated: bool = False
    threshold: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "count": self.count,
            "encoding": "runs",
            "runs": [list(run) for run in self.runs],
            "truncated": self.truncated,
            "threshold": self.threshold,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Rejected:
        runs = tuple((int(start), int(stop)) for start, stop in data.get("runs", ()))
        count = data.get("count")
        return cls(
            count=int(count) if count is not None else sum(stop - start for start, stop in runs),
            runs=runs,
            truncated=bool(data.get("truncated", False)),
            threshold=_float_or_none(data.get("threshold")),
        )


@dataclass(frozen=True)
class SolverStatus:
    """How an iterative method's solver ended.

    Attributes
    ----------
    converged : bool or None
        Whether it met its tolerance (None: not said).
    iterations : int or None
        Iterations (or function evaluations) it took.
    problem : str or None
        Why its result cannot be trusted, in words (the verdict then refuses it), or None.
    message : str or None
        The solver's own message, when it gives one.
    """

    converged: bool | None = None
    iterations: int | None = None
    problem: str | None = None
    message: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"converged": self.converged, "iterations": self.iterations, "problem": self.problem,
                "message": self.message}  # fmt: skip

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SolverStatus:
        converged, iterations = data.get("converged"), data.get("iterations")
        problem, message = data.get("problem"), data.get("message")
        return cls(
            converged=None if converged is None else bool(converged),
            iterations=None if iterations is None else int(iterations),
            problem=None if problem is None else str(problem),
            message=None if message is None else str(message),
        )


@dataclass(frozen=True)
class AutoChoice:
    """What ``auto`` chose and why.

    Attributes
    ----------
    model : str
        The model chosen: ``"sphere"``, ``"diag"`` or ``"full"``.
    chosen : str
        Its name as shown (``"robust/full"`` when fitted robustly).
    method_used : str
        The method that fitted it (``"ml"``, ``"robust/ml"`` ...).
    reason : str
        Why, in words (every model's fate).
    omitted : mapping or None
        A distortion the chosen model may leave out, which a richer model that the samples do not determine
        shows: ``model`` (that model), ``heading_deg`` (the heading error it can cause), ``heading_difference_deg``
        and ``witness_heading_sigma_deg``.
    """

    model: str
    chosen: str = ""
    method_used: str = ""
    reason: str = ""
    omitted: Mapping[str, Any] | None = None

    @property
    def omitted_heading_deg(self) -> float:
        """The heading error (degrees) of the omitted distortion, 0 when none."""
        value = (self.omitted or {}).get("heading_deg")
        return float(value) if isinstance(value, (int, float)) and value > 0 else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "chosen": self.chosen, "method_used": self.method_used, "reason": self.reason,
                "omitted": None if self.omitted is None else dict(self.omitted)}  # fmt: skip

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> AutoChoice:
        omitted = data.get("omitted")
        return cls(
            model=str(data["model"]),
            chosen=str(data.get("chosen") or data["model"]),
            method_used=str(data.get("method_used", "")),
            reason=str(data.get("reason", "")),
            omitted=None if omitted is None else dict(omitted),
        )


@dataclass(frozen=True)
class VectorFacts:
    """What a fit against a reference field (``vector``) found beside the calibration.

    Attributes
    ----------
    lag_s : float or None
        The reference's lag behind the samples, seconds (None: no time stamps, no lag fitted).
    lag_sigma_s : float or None
        Its one-sigma, seconds.
    alignment_sigma_deg : float or None
        One-sigma of the rotation into the vehicle's axes, degrees.
    gravity : mapping or None
        The gravity rows' facts (used, rows, of, dropped, notes, note), when an accelerometer was given.
    """

    lag_s: float | None = None
    lag_sigma_s: float | None = None
    alignment_sigma_deg: float | None = None
    gravity: Mapping[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"lag_s": self.lag_s, "lag_sigma_s": self.lag_sigma_s, "alignment_sigma_deg": self.alignment_sigma_deg,
                "gravity": None if self.gravity is None else dict(self.gravity)}  # fmt: skip

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> VectorFacts:
        gravity = data.get("gravity")
        return cls(
            lag_s=_float_or_none(data.get("lag_s")),
            lag_sigma_s=_float_or_none(data.get("lag_sigma_s")),
            alignment_sigma_deg=_float_or_none(data.get("alignment_sigma_deg")),
            gravity=None if gravity is None else dict(gravity),
        )


@dataclass(frozen=True)
class GyroFacts:
    """What the gyro-aided fit (``gyro``) found beside the calibration.

    Attributes
    ----------
    mapping : str
        The gyroscope-to-magnetometer axis mapping used (a firmware rotation name, or ``"general"``).
    nearest_mapping : str
        The named mapping nearest the rotation found.
    angle_from_nearest_deg : float or None
        How far the rotation found is from it, degrees.
    rotation : tuple of tuple of float
        The rotation from the gyroscope's axes into the magnetometer's, 3x3 rows.
    sensor_matrix : tuple of tuple of float or None
        The magnitude-only part of the correction (symmetric, the sensor's own axes), 3x3 rows.
    bias : tuple of float or None
        The gyroscope's bias, rad/s, and its one-sigma ``bias_sigma``.
    heading_sigma_deg : float or None
        The heading one-sigma, degrees.
    lag_s : float
        The magnetometer's lag behind the gyroscope, seconds.
    gravity : mapping or None
        The gravity rows' facts, when an accelerometer was given.
    """

    mapping: str
    nearest_mapping: str = ""
    angle_from_nearest_deg: float | None = None
    rotation: tuple[tuple[float, ...], ...] = ()
    sensor_matrix: tuple[tuple[float, ...], ...] | None = None
    bias: tuple[float, ...] | None = None
    bias_sigma: tuple[float, ...] | None = None
    heading_sigma_deg: float | None = None
    lag_s: float = 0.0
    gravity: Mapping[str, Any] | None = field(default=None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "mapping": self.mapping,
            "nearest_mapping": self.nearest_mapping,
            "angle_from_nearest_deg": self.angle_from_nearest_deg,
            "rotation": [list(row) for row in self.rotation],
            "sensor_matrix": None if self.sensor_matrix is None else [list(row) for row in self.sensor_matrix],
            "bias": None if self.bias is None else list(self.bias),
            "bias_sigma": None if self.bias_sigma is None else list(self.bias_sigma),
            "heading_sigma_deg": self.heading_sigma_deg,
            "lag_s": self.lag_s,
            "gravity": None if self.gravity is None else dict(self.gravity),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GyroFacts:
        sensor, gravity = data.get("sensor_matrix"), data.get("gravity")
        return cls(
            mapping=str(data["mapping"]),
            nearest_mapping=str(data.get("nearest_mapping", "")),
            angle_from_nearest_deg=_float_or_none(data.get("angle_from_nearest_deg")),
            rotation=tuple(tuple(float(v) for v in row) for row in data.get("rotation", ())),
            sensor_matrix=None if sensor is None else tuple(tuple(float(v) for v in row) for row in sensor),
            bias=_floats(data.get("bias")),
            bias_sigma=_floats(data.get("bias_sigma")),
            heading_sigma_deg=_float_or_none(data.get("heading_sigma_deg")),
            lag_s=float(data.get("lag_s") or 0.0),
            gravity=None if gravity is None else dict(gravity),
        )


@dataclass(frozen=True)
class LogCompass:
    """The compass of a flight log (or bag) a calibration was fitted on: what an export writes it for.

    Attributes
    ----------
    id : str
        The compass's id in the log (``"MAG/1"``, ``"sensor_mag/0"``, ``"RAW_IMU"``, a bag's topic), as
        ``sensor=`` chooses it.
    slot : int or None
        The firmware's compass slot (0-based): where an export writes the calibration (``COMPASS_OFS2_*`` for
        slot 1, ``CAL_MAG1_*``).
    device_id : int or None
        The firmware's device id of that compass (``COMPASS_DEV_ID``, ``CAL_MAGn_ID``), when the log says it.
    applied_rotation : tuple of tuple of float or None
        The rotation R0 the firmware had already applied to the samples logged (``board = R0 @ sensor``,
        ArduPilot's MAG after ``COMPASS_ORIENT``), 3x3 rows; an export of a vehicle-frame calibration
        includes it. None: the samples are the sensor's own readings.
    calibration_in_use : str or None
        The firmware's calibration that the samples still carry and that the log does not let magfit undo,
        in words: the fit is a residual on top of it, which the firmware formats refuse to write. None: raw.
    """

    id: str
    slot: int | None = None
    device_id: int | None = None
    applied_rotation: tuple[tuple[float, ...], ...] | None = None
    calibration_in_use: str | None = None

    def to_dict(self) -> dict[str, Any]:
        rotation = None if self.applied_rotation is None else [list(row) for row in self.applied_rotation]
        return {"id": self.id, "slot": self.slot, "device_id": self.device_id, "applied_rotation": rotation,
                "calibration_in_use": self.calibration_in_use}  # fmt: skip

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LogCompass:
        rotation, in_use = data.get("applied_rotation"), data.get("calibration_in_use")
        if rotation is not None:
            rotation = tuple(tuple(float(v) for v in row) for row in rotation)
            if len(rotation) != 3 or any(len(row) != 3 for row in rotation):
                raise ValueError("'applied_rotation' must be a 3x3 matrix")
        return cls(
            id=_text(data["id"], "id"),
            slot=_whole(data.get("slot"), "slot"),
            device_id=_whole(data.get("device_id"), "device_id"),
            applied_rotation=rotation,
            calibration_in_use=None if in_use is None else _text(in_use, "calibration_in_use"),
        )


@dataclass(frozen=True)
class SampleSource:
    """Where a calibration's samples came from: the file and, for a samples file, the columns fitted.

    ``magfit apply`` reads the same columns of another file by these: their names when the fitted file had a
    header, else their positions in a file of as many columns.

    Attributes
    ----------
    file : str
        The file's name (without its folder).
    unit : str or None
        The samples' unit, as the calibration is labelled.
    columns : tuple of str or None
        A samples file's x, y, z columns, as named (``"mag_x"``, or ``"column 2"`` without a header); None
        for a log (its compass: :class:`LogCompass`).
    column_indices : tuple of int or None
        Their 0-based positions in the file.
    header : bool or None
        Whether the file has a header line of column names.
    n_columns : int or None
        How many columns the file has.
    streams : tuple of str
        Where a method's other streams came from (reference, gyroscope, time ...), one line each.
    """

    file: str
    unit: str | None = None
    columns: tuple[str, ...] | None = None
    column_indices: tuple[int, ...] | None = None
    header: bool | None = None
    n_columns: int | None = None
    streams: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"file": self.file, "unit": self.unit}
        if self.columns is not None:
            data["columns"] = list(self.columns)
        if self.column_indices is not None:
            data["column_indices"] = list(self.column_indices)
        if self.header is not None:
            data["header"] = self.header
        if self.n_columns is not None:
            data["n_columns"] = self.n_columns
        if self.streams:
            data["streams"] = list(self.streams)
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SampleSource:
        columns, indices, header, unit = (data.get(k) for k in ("columns", "column_indices", "header", "unit"))
        if header is not None and not isinstance(header, bool):
            raise TypeError(f"'header' must be true or false, got {type(header).__name__}")
        return cls(
            file=_text(data["file"], "file"),
            unit=None if unit is None else _text(unit, "unit"),
            columns=None if columns is None else tuple(_text(c, "columns") for c in columns),
            column_indices=None if indices is None else tuple(_index(i) for i in indices),
            header=header,
            n_columns=_whole(data.get("n_columns"), "n_columns"),
            streams=tuple(_text(line, "streams") for line in data.get("streams") or ()),
        )


#: The typed fields of a calibration read from ``details`` keys (schema version 1), each with its reader.
FACT_FIELDS = (
    "support", "options", "known_field", "rejected", "solver", "auto", "vector", "gyro", "sensor", "source"
)  # fmt: skip


def split_details(details: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The typed facts that a version-1 ``details`` holds under its fixed keys, and the rest of ``details``.

    Returns ``(facts, rest)``: ``facts`` maps the names of :data:`FACT_FIELDS` found to their typed records
    (``options`` to a dict), ``rest`` is ``details`` without the keys read. ``details["sensor"]`` becomes
    :class:`LogCompass`; ``details["source"]`` becomes :class:`SampleSource`, and the log compass it names
    (its ``sensor`` and ``device_id``) a :class:`LogCompass` when ``details["sensor"]`` is absent. Raises
    what the records' readers raise (``KeyError``, ``TypeError``, ``ValueError``) on a malformed entry.
    """
    rest = dict(details)
    facts: dict[str, Any] = {}
    if isinstance(rest.get("support"), Mapping):
        facts["support"] = Support.from_dict(dict(rest.pop("support")))
    if isinstance(rest.get("options"), Mapping):
        facts["options"] = dict(rest.pop("options"))
    if rest.get("field_strength_given"):
        rest.pop("field_strength_given")
        facts["known_field"] = KnownField(
            fitted=_float_or_none(rest.pop("fitted_field_strength", None)),
            pinned=bool(rest.pop("radius_pinned", False)),
        )
    if isinstance(rest.get("rejected"), Mapping):
        stored = dict(rest.pop("rejected"))
        count = rest.pop("n_rejected", None)
        threshold = rest.pop("threshold", None)
        facts["rejected"] = Rejected.from_dict({**stored, "count": count, "threshold": threshold})
    solver = rest.pop("solver", None) if isinstance(rest.get("solver"), Mapping) else None
    if solver is not None or any(key in rest for key in ("converged", "solver_problem")):
        solver = dict(solver or {})
        facts["solver"] = SolverStatus(
            converged=cast(bool | None, rest.pop("converged", None)),
            iterations=_int_or_none(rest.pop("iterations", solver.get("iterations"))),
            problem=cast(str | None, rest.pop("solver_problem", None)),
            message=None if solver.get("message") is None else str(solver["message"]),
        )
    if "chosen_model" in rest:
        omitted = rest.pop("omitted_distortion", None)
        facts["auto"] = AutoChoice.from_dict(
            {
                "model": rest.pop("chosen_model"),
                "chosen": rest.pop("chosen", None),
                "method_used": rest.pop("method_used", ""),
                "reason": rest.pop("reason", ""),
                "omitted": omitted,
            }
        )
        rest.pop("weak", None)  # the chosen model's weaknesses before the verdict: the verdict's are in support
    if "mapping" in rest and "gyro_bias" in rest:  # the gyro-aided fit's
        facts["gyro"] = GyroFacts.from_dict(
            {
                "mapping": rest.pop("mapping"),
                "nearest_mapping": rest.pop("nearest_mapping", ""),
                "angle_from_nearest_deg": rest.pop("angle_from_nearest_deg", None),
                "rotation": rest.pop("rotation", ()),
                "sensor_matrix": rest.pop("sensor_matrix", None),
                "bias": rest.pop("gyro_bias"),
                "bias_sigma": rest.pop("gyro_bias_sigma", None),
                "heading_sigma_deg": rest.pop("heading_sigma_deg", None),
                "lag_s": rest.pop("lag_s", 0.0),
                "gravity": rest.pop("gravity", None),
            }
        )
    elif "alignment_sigma_deg" in rest:  # the fit against a reference field's
        facts["vector"] = VectorFacts.from_dict(
            {
                "lag_s": rest.pop("lag_s", None),
                "lag_sigma_s": rest.pop("lag_sigma_s", None),
                "alignment_sigma_deg": rest.pop("alignment_sigma_deg"),
                "gravity": rest.pop("gravity", None),
            }
        )
    if isinstance(rest.get("sensor"), Mapping) and "id" in rest["sensor"]:  # a log's compass
        facts["sensor"] = LogCompass.from_dict(rest.pop("sensor"))
    if isinstance(rest.get("source"), Mapping) and "file" in rest["source"]:
        source = dict(rest.pop("source"))
        compass, device_id = source.pop("sensor", None), source.pop("device_id", None)  # a log's: its compass's
        if "sensor" not in facts and isinstance(compass, str):
            facts["sensor"] = LogCompass(id=compass, device_id=_whole(device_id, "device_id"))
        facts["source"] = SampleSource.from_dict(source)
    return facts, rest


def _text(value: Any, name: str) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{name!r} must be text, got {type(value).__name__}")
    return value


def _whole(value: Any, name: str) -> int | None:
    """A JSON integer (not a boolean, not a float), or None."""
    if value is None:
        return None
    if isinstance(value, bool):
        raise TypeError(f"{name!r} must be an integer or null, got {value!r}")
    try:
        return operator.index(value)  # an int or a NumPy integer; a float or text is refused
    except TypeError:
        raise TypeError(f"{name!r} must be an integer or null, got {value!r}") from None


def _index(value: Any) -> int:
    index = _whole(value, "column_indices")
    if index is None or index < 0:
        raise ValueError(f"'column_indices' must be column numbers from 0, got {value!r}")
    return index


def _int_or_none(value: Any) -> int | None:
    return None if value is None else int(value)
