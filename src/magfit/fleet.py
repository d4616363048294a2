"""Fleets: many recordings of many vehicles in one run, one table, each vehicle's flights combined.

The data flow, one way:

    paths → recordings (folders, globs, @lists) → per recording, in parallel: calibrate_file's fit and verdict
    for each compass (a "flight" row) and the sufficient statistics of the samples its fit kept → per vehicle
    and compass: the flights in time order, split where they stop agreeing (from the statistics alone) → each
    part's flights read again and fitted together with the run's method, judged as any recording (a "combined"
    row)

**Why statistics.** The scatter ``S = Σ d(z) d(z)ᵀ`` of the design vector (:mod:`magfit.statistics`) is a few
hundred numbers per compass, and scatters of different recordings of one sensor add: whether flights agree is
decided on them in the client (and kept in the journal), without holding any flight's samples. Several partial
flights, each covering a part of the sphere of directions that determines no calibration alone, together
determine one; the combined fit then runs on their samples, so that its verdict has everything a recording's
has (the halves of the union, the correlation in time, the heading one-sigma).

**Do the flights agree?** Merging is only right while the sensor's distortion stayed the same. A calibration
``(V, M, B)`` is the quadric ``|M (x − V)|² / B² − 1 = 0``; in a recording's canonical frame
``x = s z + c`` it is ``θᵀ d(z)`` with (A = MᵀM / B², the design's √2 on the cross terms)

    θ = (A₁₁, A₂₂, A₃₃, √2 A₁₂, √2 A₁₃, √2 A₂₃) s²,  2 s A (c − V),  (c − V)ᵀ A (c − V) − 1

so the mean squared algebraic residual of a recording against any calibration is ``θᵀ S θ / n`` without its
samples; half its root is the RMS distance to the ellipsoid in units of the field (first order). A flight whose
distance to the calibration of the flights merged with it exceeds its distance to its own best ellipsoid
(each about its own field strength: a flight at another site is no change) significantly
(:data:`DISAGREEMENT_CHI2`) and by more than :data:`DISAGREEMENT_FLOOR` of the field sits on another
ellipsoid: the vehicle was magnetised, its hardware or payload changed, or it flew where the Earth's field
differs. The flights from it on start a new part, named with its date and size.

**Where it runs.** Local processes by default (this one, and the standard library's process pool for the
others, forked from a server that imported the fitting modules once: no set-up); a Dask cluster with
``scheduler="tcp://host:8786"`` (the ``fleet`` extra's ``distributed``). Each recording is one task, read
once (:func:`magfit.calibrate_file` gives each compass's statistics, the log's date and its vehicle's
identity); a recording that fails is one row with its reason and never stops the run.

**Resumable.** Every finished recording is appended, with its compasses' statistics, to a journal beside the
table (``TABLE.journal.jsonl``, one JSON line per recording, flushed); a run given the same table skips the
recordings its journal holds fitted the same way from the same file (size, modification time, settings),
runs again those that failed, and rewrites the table (atomically) at the end.
"""

from __future__ import annotations

import datetime
import functools
import glob
import json
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .calibration import Calibration
from .errors import DataFileError, MagfitError, OptionError, SampleError
from .remedy import Audience, audience, for_command_line, option
from .sources.position import Position
from .statistics import Statistics

__all__ = [
    "DISAGREEMENT_CHI2",
    "DISAGREEMENT_FLOOR",
    "FleetResult",
    "FleetRow",
    "fleet",
    "recordings",
    "residual_rms",
]

#: A flight disagrees with those merged with it when its excess distance to their ellipsoid over its own is
#: significant (:data:`DISAGREEMENT_CHI2`) and at least this share of the field (RMS): an offset that moved by
#: about 1.5 % of the field (some 1.5° of heading at 60° of dip) between flights; smaller excesses are left to
#: the combined fit's own verdict (its halves).
DISAGREEMENT_FLOOR = 0.004
#: Refusal codes that only say a flight covers too little of the sphere (``model_inadequate``: a richer model
#: would describe it but is not determined) — its samples still join the union, whose verdict judges them.
PARTIAL_CODES = frozenset(
    {
        "undetermined", "weakly_determined", "single_axis", "low_coverage", "restricted_attitude", "too_few_samples",
        "model_inadequate",
    }
)  # fmt: skip
#: File name endings the folder walk takes as recordings (after a compression suffix).
RECORDING_SUFFIXES = (".bin", ".ulg", ".tlog", ".csv", ".tsv", ".txt", ".npy", ".npz", ".bag", ".mcap")
_COMPRESSED = (".gz", ".bz2", ".xz", ".zst")
#: The combined fit of a vehicle-frame method's flights (vector, gyro: their streams are not read again): the
#: magnitude-only fit without the algebraic fit's bias.
COMBINE_METHOD = "als"


@dataclass(frozen=True)
class FleetRow:
    """One row of the fleet table: one compass of one recording ("flight"), or a vehicle's flights combined.

    Attributes
    ----------
    kind : {"flight", "combined", "error"}
        A compass of one recording, the union of a vehicle's agreeing flights, or a recording that could not
        be read or fitted at all.
    vehicle : str
        The vehicle: the log's own identity where it has one (the flight controller's board and unique id:
        ArduPilot's boot message, PX4's ``sys_uuid``), else the folder that holds the recording, as a path below
        the folder that holds every recording of the run.
    path : str
        The recording ("flight", "error"); the recordings merged, ``;``-separated ("combined").
    sensor, device_id : str, int or None
        The compass (a log's id, e.g. ``MAG/0``; empty for a samples file) and the firmware's device id.
    date : str
        When the recording was made (ISO date and time where the log says; else the file's modification
        time); for a combined row, the first and last flight's, joined by ``/``.
    method, verdict : str
        The method and its verdict: ``supported``, ``weak`` or ``refused`` (``error`` for kind ``error``).
    codes, reason : str
        The verdict's reason codes (``;``-separated, :data:`magfit.REASON_CODES`) and its words; an error row's
        are its error's (an input error without a code of its own: ``unreadable_file``, ``bad_option``,
        ``bad_samples``).
    offset_x … matrix_zz, field_strength, unit
        The calibration (``corrected = matrix @ (raw − offset)``); NaN when refused.
    n_samples, flights : int
        Samples fitted; recordings merged (1 for a flight).
    field_vs_model : float
        The fitted field strength over the World Magnetic Model's at the recording (NaN when not known).
    heading_sigma_deg : float
        The heading one-sigma at level the verdict states (NaN when not known).
    """

    kind: Literal["flight", "combined", "error"]
    vehicle: str
    path: str
    sensor: str = ""
    device_id: int | None = None
    date: str = ""
    method: str = ""
    verdict: str = "error"
    codes: str = ""
    reason: str = ""
    offset_x: float = math.nan
    offset_y: float = math.nan
    offset_z: float = math.nan
    matrix_xx: float = math.nan
    matrix_xy: float = math.nan
    matrix_xz: float = math.nan
    matrix_yx: float = math.nan
    matrix_yy: float = math.nan
    matrix_yz: float = math.nan
    matrix_zx: float = math.nan
    matrix_zy: float = math.nan
    matrix_zz: float = math.nan
    field_strength: float = math.nan
    unit: str = ""
    n_samples: int = 0
    flights: int = 1
    field_vs_model: float = math.nan
    heading_sigma_deg: float = math.nan

    @property
    def offset(self) -> np.ndarray:
        return np.array([self.offset_x, self.offset_y, self.offset_z])

    @classmethod
    def columns(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


@dataclass(frozen=True)
class _Compass:
    """A compass's samples as statistics, with what grouping and merging need (journal only).

    ``key`` names the compass across recordings: a log's device id (else its id in the log), a samples file's
    three column names.
    """

    sensor: str
    device_id: int | None
    unit: str
    statistics: Statistics
    mergeable: bool
    key: str = ""


@dataclass(frozen=True)
class _Outcome:
    """What one recording gave: its rows and its compasses' statistics."""

    path: str
    rows: tuple[FleetRow, ...]
    compasses: tuple[_Compass, ...] = ()
    fingerprint: str = ""  # the file (size, modification time) and the settings it was fitted with

    def to_json(self) -> str:
        return json.dumps(
            {
                "path": self.path,
                "fingerprint": self.fingerprint,
                "rows": [asdict(row) for row in self.rows],
                "compasses": [
                    {
                        "sensor": c.sensor,
                        "device_id": c.device_id,
                        "unit": c.unit,
                        "mergeable": c.mergeable,
                        "key": c.key,
                        "statistics": c.statistics.to_dict(),
                    }
                    for c in self.compasses
                ],
            },
            allow_nan=True,
        )

    @classmethod
    def from_json(cls, text: str) -> _Outcome:
        data = json.loads(text)
        rows = tuple(FleetRow(**row) for row in data["rows"])
        compasses = tuple(
            _Compass(
                c["sensor"], c["device_id"], c["unit"], Statistics.from_dict(c["statistics"]), c["mergeable"],
                c.get("key", ""),
            )
            for c in data["compasses"]
        )
        return cls(data["path"], rows, compasses, str(data.get("fingerprint", "")))

    @property
    def failed(self) -> bool:
        """Nothing was read: the recording runs again on a resumed run."""
        return all(row.kind == "error" for row in self.rows) and not self.compasses


@dataclass(frozen=True)
class FleetResult:
    """What :func:`fleet` returns.

    Attributes
    ----------
    rows : tuple of FleetRow
        Every flight row (in the order of the recordings), then the combined rows.
    events : tuple of str
        Each change found between a vehicle's flights, in words (which flight, when, by how much).
    skipped : int
        Recordings already in the table's journal (a resumed run).
    output : Path or None
        The table written.
    """

    rows: tuple[FleetRow, ...]
    events: tuple[str, ...] = ()
    skipped: int = 0
    output: Path | None = None

    def combined(self) -> tuple[FleetRow, ...]:
        return tuple(row for row in self.rows if row.kind == "combined")

    def flights(self) -> tuple[FleetRow, ...]:
        return tuple(row for row in self.rows if row.kind != "combined")


# ---------------------------------------------------------------------------------------------- recordings


def recordings(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The recordings named by ``paths``: files, folders (walked for recordings), globs, and ``@LIST`` files
    that list one path per line (``#`` comments). Sorted, each once.

    Raises
    ------
    OptionError
        A path that does not exist, a glob or folder that finds nothing.
    """
    found: dict[Path, None] = {}
    for item in paths:
        text = os.fspath(item)
        if text.startswith("@"):
            listing = Path(text[1:])
            try:
                lines = listing.read_text(encoding="utf-8").splitlines()
            except OSError as error:
                raise OptionError(f"{listing}: cannot read the list of recordings ({error.strerror})") from None
            entries = [line.strip() for line in lines if line.strip() and not line.strip().startswith("#")]
            base = listing.parent
            found.update((p, None) for p in recordings(str(base / e) if not os.path.isabs(e) else e for e in entries))
            continue
        if any(char in text for char in "*?["):
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise OptionError(f"{text}: the pattern matches no file")
            found.update((p, None) for p in recordings(m for m in matches if not _written_by_fleet(Path(m))))
            continue
        path = Path(text)
        if path.is_dir() and not (path / "metadata.yaml").exists():
            walked = sorted(p for p in path.rglob("*") if _is_recording(p))
            if not walked:
                raise OptionError(
                    f"{path}: the folder holds no recording (files ending {', '.join(RECORDING_SUFFIXES)}, "
                    "compressed or not)"
                )
            found.update((p, None) for p in walked)
        elif path.is_file() and is_fleet_table(path):
            raise OptionError(f"{path} is a table written by 'magfit fleet', not a recording: leave it out")
        elif path.exists():
            found[path] = None
        else:
            raise OptionError(f"{path}: no such file or folder")
    return sorted(found)


def _is_recording(path: Path) -> bool:
    if not path.is_file() or any(part.startswith(".") for part in path.parts[-1:]):
        return False
    name = path.name.lower()
    if name.endswith(".journal.jsonl"):
        return False
    for suffix in _COMPRESSED:
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name.endswith(RECORDING_SUFFIXES) and not is_fleet_table(path)


def is_fleet_table(path: Path) -> bool:
    """Whether ``path`` is a table this module wrote (:func:`write_table`): a text file whose first line is the
    table's header (CSV) or a record with its first columns (JSON lines). A folder walked, a glob matched, finds
    the tables of earlier runs beside the recordings: never a recording."""
    head = _head(path)
    first = head.split(b"\n", 1)[0].decode("utf-8", "replace")
    return first.startswith(",".join(FleetRow.columns()[:4])) or (
        first.startswith('{"kind": ') and '"vehicle": ' in first
    )


def _written_by_fleet(path: Path) -> bool:
    """A table, a journal (``TABLE.journal.jsonl``) or an HTML report of an earlier run: what a glob such as
    ``logs/**/*`` matches beside the recordings, and never one of them."""
    if path.name.lower().endswith(".journal.jsonl"):
        return True
    return _head(path).lstrip().lower().startswith(b"<!doctype html") or is_fleet_table(path)


def _head(path: Path) -> bytes:
    try:
        with path.open("rb") as handle:
            return handle.read(200)
    except OSError:
        return b""


def vehicle_of(path: Path, root: Path | None = None) -> str:
    """The vehicle a recording belongs to: the folder that holds it, as a path below ``root`` (the folder that
    holds every recording of the run: ``droneA/logs`` and ``droneB/logs`` are two vehicles); the folder's own
    name when it is ``root``."""
    folder = path.resolve().parent
    if root is not None:
        try:
            below = folder.relative_to(root.resolve())
        except ValueError:
            below = None
        if below is not None and str(below) not in ("", "."):
            return below.as_posix()
    return folder.name or str(folder)


# ---------------------------------------------------------------------------------------------- one recording


@dataclass(frozen=True)
class _Settings:
    method: str
    field_strength: float | Literal["wmm"] | None
    unit: str | None
    location: tuple[float, float, float] | None
    date: str | None
    #: Who reads the rows' reasons (:func:`magfit.remedy.audience`): a worker process says them as the run does.
    audience: Audience = "python"


def _in_the_run_words(function: Callable[..., Any]) -> Callable[..., Any]:
    """``function(*task, settings)`` with its messages built for the run's reader (``settings.audience``), in
    whichever process it runs: a remedy says ``--location`` in every row of a command-line run."""

    @functools.wraps(function)
    def run(*arguments: Any) -> Any:
        if arguments[-1].audience == "command line" and audience() != "command line":
            with for_command_line():
                return function(*arguments)
        return function(*arguments)

    return run


@_in_the_run_words
def _fit_recording(path: Path, vehicle: str, settings: _Settings) -> _Outcome:
    """Every compass of one recording: its row and its statistics; a failure is one row, never an exception.

    The file is read once: :func:`magfit.calibrate_file` gives each compass's statistics, the log's GNSS time
    and the vehicle's own identity with its fits. Only a compass whose samples were not held (a samples file
    streamed), or that was refused for covering too little, is read again for its statistics.
    """
    fingerprint = _fingerprint(path, settings)
    try:
        outcome = _fit_recording_or_raise(path, vehicle, settings)
    except MagfitError as error:
        compasses, logged, identity = _compasses_anyway(path, settings, error)
        if identity is None and not compasses:
            from .sources import vehicle_identity

            identity = vehicle_identity(path)
        # A usage error (an option this file cannot serve: no place for the World Magnetic Model) is no verdict.
        refused = bool(error.codes) and not isinstance(error, OptionError)
        row = FleetRow("error", identity or vehicle, str(path), date=logged or _file_date(path),
                       method=settings.method, verdict="refused" if refused else "error",
                       codes=_codes_of(error), reason=_one_line(str(error)))  # fmt: skip
        outcome = _Outcome(str(path), (row,), compasses)
    except (OSError, MemoryError) as error:
        row = FleetRow("error", vehicle, str(path), codes=_codes_of(error), reason=_one_line(str(error)))
        outcome = _Outcome(str(path), (row,))
    return _Outcome(outcome.path, outcome.rows, outcome.compasses, fingerprint)


def _codes_of(error: BaseException) -> str:
    """A failing row's reason codes (``;``-separated): the error's own; else that of its kind, an input error's
    (``unreadable_file``, ``bad_option``, ``bad_samples``) or ``unclassified``."""
    if isinstance(error, MagfitError) and error.codes:
        return ";".join(error.codes)
    if isinstance(error, (DataFileError, OSError, MemoryError)):  # (MemoryError: too big to read here)
        return "unreadable_file"
    if isinstance(error, OptionError):
        return "bad_option"
    if isinstance(error, SampleError):
        return "bad_samples"
    return "unclassified"


def _fingerprint(path: Path, settings: _Settings) -> str:
    """What a journal entry was made from: the file's size and modification time, and the settings."""
    try:
        stat = path.stat()
        file = f"{stat.st_size}:{stat.st_mtime_ns}"
    except OSError:
        file = "missing"
    return f"{file}|{settings.method}|{settings.unit}|{settings.field_strength}|{settings.location}|{settings.date}"


def _fit_recording_or_raise(path: Path, vehicle: str, settings: _Settings) -> _Outcome:
    from .pipeline import calibrate_file

    result = calibrate_file(
        path, settings.method, unit=settings.unit, field_strength=settings.field_strength,
        location=settings.location, date=settings.date,
    )  # fmt: skip
    vehicle = result.identity or vehicle  # the log's own board and id, wherever its file lies
    logged = _gnss_date(result.position)
    date = logged or _file_date(path)  # every row of a recording dated alike: its log's GNSS time where it has one
    rows: list[FleetRow] = []
    compasses: list[_Compass] = []
    again: dict[str, bool] = {}  # compasses to read again for their statistics: sensor -> mergeable
    for compass in result.compasses:
        cal = compass.calibration
        sensor = _sensor_of(cal)
        device_id = cal.sensor.device_id if cal.sensor is not None else None
        model = compass.model_field or result.model_field
        ratio = math.nan
        if model is not None and cal.unit:
            try:
                ratio = cal.field_strength / model.field.total_in(cal.unit)
            except MagfitError:
                ratio = math.nan
        rows.append(_row("flight", vehicle, str(path), cal, sensor, device_id, date, ratio))
        if compass.statistics is None or compass.statistics.n == 0:
            again[sensor] = True
            continue
        magnetometer = compass.magnetometer
        if magnetometer is None:
            key = "columns " + ",".join(str(column) for column in compass.columns)
            compasses.append(_Compass("", None, settings.unit or cal.unit or "", compass.statistics, True, key))
        else:
            key = f"device {magnetometer.device_id}" if magnetometer.device_id is not None else magnetometer.id
            compasses.append(_Compass(magnetometer.id, magnetometer.device_id, settings.unit or magnetometer.unit,
                                      compass.statistics, True, key))  # fmt: skip
    failed = {failure.sensor for failure in result.failures}
    for failure in result.failures:
        if failure.codes and set(failure.codes) <= PARTIAL_CODES:
            again[failure.sensor] = True
    read = _Read()
    if again or failed:  # the statistics of what was not held; a refused compass's device id
        read = _read_compasses(path, settings.unit, {}, set(again))
    reads = {c.sensor: c for c in read.compasses}
    compasses += [reads[sensor] for sensor in again if sensor not in failed and sensor in reads]
    for failure in result.failures:
        rows.append(FleetRow("flight", vehicle, str(path), sensor=failure.sensor,
                             device_id=read.devices.get(failure.sensor), date=date, method=settings.method,
                             verdict="refused", codes=";".join(failure.codes) or "unclassified",
                             reason=_one_line(failure.reason)))  # fmt: skip
        if failure.sensor in reads:
            compasses.append(reads[failure.sensor])
    return _Outcome(str(path), tuple(rows), tuple(compasses))


def _sensor_of(calibration: Calibration) -> str:
    return calibration.sensor.id if calibration.sensor is not None else ""


def _compasses_anyway(
    path: Path, settings: _Settings, error: MagfitError
) -> tuple[tuple[_Compass, ...], str | None, str | None]:
    """A recording refused only for covering too little still gives its statistics to its vehicle's union
    (with the log's GNSS date and identity, read in the same pass)."""
    if not error.codes or not set(error.codes) <= PARTIAL_CODES:
        return (), None, None
    try:
        read = _read_compasses(path, settings.unit, {})
    except (MagfitError, OSError, MemoryError):
        return (), None, None
    return read.compasses, read.date, read.identity


@dataclass(frozen=True)
class _Read:
    """What :func:`_read_compasses` found: the compasses' statistics, the log's GNSS date, the vehicle's
    identity, and each compass's device id."""

    compasses: tuple[_Compass, ...] = ()
    date: str | None = None
    identity: str | None = None
    devices: dict[str, int | None] = field(default_factory=dict)


def _read_compasses(
    path: Path, unit: str | None, fitted: dict[str, Calibration], sensors: set[str] | None = None
) -> _Read:
    """The statistics of each compass of a recording (a log's every usable compass, or those in ``sensors``;
    a samples file's), of the samples its fit kept (a robust fit's rejected samples — spikes, a passing magnet —
    stay out of the union); with the log's GNSS date, its vehicle's identity and its compasses' device ids."""
    from .outliers import kept_statistics  # the same rule the diagnostics leave those samples out by
    from .sources import log_kind, open_source

    def kept(samples: np.ndarray, sensor: str) -> Statistics:
        return kept_statistics(fitted.get(sensor), samples)

    if log_kind(path) is None:
        from .io import read_samples

        table = read_samples(path)
        key = "columns " + ",".join(str(column) for column in table.columns)
        return _Read((_Compass("", None, unit or "", kept(table.samples, ""), True, key),))
    source = open_source(path, everything=False)
    compasses = []
    devices = {magnetometer.id: magnetometer.device_id for magnetometer in source.magnetometers}
    for magnetometer in source.magnetometers:
        if magnetometer.problem is not None or magnetometer.n_samples == 0:
            continue
        if sensors is not None and magnetometer.id not in sensors:
            continue
        try:
            samples = source.read(magnetometer.id).samples
        except MagfitError:
            continue
        if len(samples) == 0:
            continue
        key = f"device {magnetometer.device_id}" if magnetometer.device_id is not None else magnetometer.id
        compasses.append(_Compass(magnetometer.id, magnetometer.device_id, unit or magnetometer.unit,
                                  kept(samples, magnetometer.id), True, key))  # fmt: skip
    return _Read(tuple(compasses), _gnss_date(source.position), source.identity, devices)


def _gnss_date(position: Position | None) -> str | None:
    """A log's date: its first GNSS fix's time (None without one)."""
    if position is not None and math.isfinite(position.time_s):
        return _utc(position.time_s)
    return None


def _row(
    kind: Literal["flight", "combined"],
    vehicle: str,
    path: str,
    cal: Calibration,
    sensor: str,
    device_id: int | None,
    date: str,
    ratio: float = math.nan,
    flights: int = 1,
) -> FleetRow:
    diagnostics = cal.diagnostics
    support = diagnostics.support if diagnostics is not None else None
    verdict = support.verdict if support is not None else "supported"
    if support is not None and support.forced:
        verdict = "refused"
    heading = math.nan
    if diagnostics is not None and diagnostics.uncertainty is not None:
        value = diagnostics.uncertainty.heading_sigma_deg
        heading = math.nan if value is None else float(value)
    matrix = np.asarray(cal.matrix)
    words = "; ".join(support.warnings) if support is not None else ""
    return FleetRow(
        kind, vehicle, path, sensor=sensor, device_id=device_id, date=date, method=cal.method, verdict=verdict,
        codes=";".join(support.codes) if support is not None else "", reason=_one_line(words),
        offset_x=float(cal.offset[0]), offset_y=float(cal.offset[1]), offset_z=float(cal.offset[2]),
        matrix_xx=float(matrix[0, 0]), matrix_xy=float(matrix[0, 1]), matrix_xz=float(matrix[0, 2]),
        matrix_yx=float(matrix[1, 0]), matrix_yy=float(matrix[1, 1]), matrix_yz=float(matrix[1, 2]),
        matrix_zx=float(matrix[2, 0]), matrix_zy=float(matrix[2, 1]), matrix_zz=float(matrix[2, 2]),
        field_strength=float(cal.field_strength), unit=cal.unit or "", n_samples=int(cal.n_samples or 0),
        flights=flights, field_vs_model=ratio, heading_sigma_deg=heading,
    )  # fmt: skip


def _file_date(path: Path) -> str:
    """A recording's date when it logs none: the file's modification time."""
    try:
        return _utc(path.stat().st_mtime)
    except OSError:
        return ""


def _utc(stamp: float) -> str:
    return datetime.datetime.fromtimestamp(stamp, tz=datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def _one_line(text: str) -> str:
    return " ".join(text.split())


# ---------------------------------------------------------------------------------------------- combining


def _theta(statistics: Statistics, calibration: Calibration) -> np.ndarray:
    """The quadric of ``calibration`` in ``statistics``' canonical frame (module docstring)."""
    centre, scale = statistics.centre, statistics.scale
    matrix = np.asarray(calibration.matrix)
    a = matrix.T @ matrix / calibration.field_strength**2
    shift = centre - np.asarray(calibration.offset)
    root2 = math.sqrt(2.0)
    return np.array([
        a[0, 0] * scale**2, a[1, 1] * scale**2, a[2, 2] * scale**2,
        root2 * a[0, 1] * scale**2, root2 * a[0, 2] * scale**2, root2 * a[1, 2] * scale**2,
        *(2.0 * scale * (a @ shift)),
        float(shift @ a @ shift) - 1.0,
    ])  # fmt: skip


def residual_rms(statistics: Statistics, calibration: Calibration, own_radius: bool = False) -> float:
    """RMS distance of the samples behind ``statistics`` to ``calibration``'s ellipsoid, in units of its field.

    Half the root of ``θᵀ S θ / n`` (module docstring): the first-order distance of the algebraic residual
    ``|M (x − V)|² / B² − 1``, computed from the statistics alone. ``own_radius``: about the samples' own mean
    of ``|M (x − V)|² / B²`` instead of 1 (``θᵀ S θ / n − (θᵀ s̄)²``, s̄ the mean design vector): a recording
    made where the Earth's field is stronger or weaker is not off the ellipsoid's shape and centre.
    """
    theta = _theta(statistics, calibration)
    scatter = statistics.scatter
    mean_square = float(theta @ scatter @ theta) / statistics.n
    if own_radius:
        mean_square -= float(theta @ scatter[:, 9] / statistics.n) ** 2
    return 0.5 * math.sqrt(max(mean_square, 0.0))


def _own_fit(statistics: Statistics) -> Calibration | None:
    """A flight's own best ellipsoid (determined or not): what its noise and model error leave."""
    from .fit import fit

    try:
        return fit(statistics, method="ellipsoid", diagnostics=False, allow_undetermined=True)
    except MagfitError:
        return None


def _union_fit(parts: Sequence[Statistics]) -> Calibration | None:
    return _own_fit(sum(parts, Statistics()))


@dataclass
class _Flight:
    row: FleetRow
    compass: _Compass
    own: float = math.nan  # RMS distance to its own ellipsoid, about its own radius (units of the field)


@dataclass
class _Part:
    flights: list[_Flight] = field(default_factory=list)


#: A flight disagrees with the union when n·(d_union² − d_own²) / d_own², whose distribution is about χ² with
#: the 9 degrees of freedom of its own fit when it agrees, exceeds this (a false alarm about once in 10⁸) ...
DISAGREEMENT_CHI2 = 60.0


def _disagreement(flight: _Flight, union: Calibration) -> float:
    """The flight's excess RMS distance to the union's ellipsoid over its own (units of the field), when
    significant (:data:`DISAGREEMENT_CHI2`) and larger than :data:`DISAGREEMENT_FLOOR`; else 0. A flight whose
    own ellipsoid could not be fitted never splits."""
    if not np.isfinite(flight.own) or flight.own <= 0:
        return 0.0
    union_rms = residual_rms(flight.compass.statistics, union, own_radius=True)
    excess_square = union_rms**2 - flight.own**2
    if excess_square <= 0:
        return 0.0
    statistic = flight.compass.statistics.n * excess_square / flight.own**2
    excess = math.sqrt(excess_square)
    return excess if statistic > DISAGREEMENT_CHI2 and excess > DISAGREEMENT_FLOOR else 0.0


def _split(flights: list[_Flight]) -> tuple[list[_Part], list[tuple[_Flight, float]]]:
    """The flights in time order, split before each flight that does not agree with those before it.

    Returns the parts and, for each split, the flight that starts it with the excess distance found.
    """
    parts = [_Part([flights[0]])]
    splits: list[tuple[_Flight, float]] = []
    for flight in flights[1:]:
        current = parts[-1]
        union = _union_fit([f.compass.statistics for f in (*current.flights, flight)])
        worst = 0.0 if union is None else max(_disagreement(member, union) for member in (*current.flights, flight))
        if worst > 0.0:
            parts.append(_Part([flight]))
            splits.append((flight, worst))
        else:
            current.flights.append(flight)
    return parts, splits


@dataclass(frozen=True)
class _PartTask:
    """One combined fit: a vehicle's compass over the flights of one part, read again and fitted together."""

    vehicle: str
    sensor: str
    device_id: int | None
    unit: str
    recordings: tuple[tuple[str, str], ...]  # (path, sensor id) in time order
    dates: str
    model_total: float  # the World Magnetic Model's field in ``unit`` where the flights knew it, else NaN


#: At most this many samples of a part are fitted together (a regular stride of each flight beyond it).
COMBINED_SAMPLES = 2_000_000


@_in_the_run_words
def _fit_part(task: _PartTask, settings: _Settings) -> FleetRow:
    """The combined row: the part's flights' samples (the compass's, read again), in time order, fitted with the
    run's method and judged like any recording (its verdict, the halves of the union, its heading one-sigma)."""
    from .fit import fit
    from .io import read_samples
    from .sources import log_kind, open_source

    paths = ";".join(path for path, _ in task.recordings)
    try:
        pieces = []
        for path, sensor in task.recordings:
            if log_kind(path) is None:
                pieces.append(read_samples(path).samples)
            else:
                pieces.append(open_source(path, everything=False).read(sensor or None).samples)
        total = sum(len(piece) for piece in pieces)
        step = max(1, math.ceil(total / COMBINED_SAMPLES))
        samples = np.concatenate([piece[::step] for piece in pieces])
        options: dict[str, Any] = {}
        if isinstance(settings.field_strength, float) or isinstance(settings.field_strength, int):
            options["field_strength"] = float(settings.field_strength)
        elif settings.field_strength == "wmm" and math.isfinite(task.model_total):
            options["field_strength"] = task.model_total
        method = settings.method if settings.method in _SAMPLES_METHODS else COMBINE_METHOD
        cal = fit(samples, method=method, **options)
    except MagfitError as error:
        return FleetRow("combined", task.vehicle, paths, sensor=task.sensor, device_id=task.device_id,
                        date=task.dates, method=settings.method, verdict="refused", codes=_codes_of(error),
                        reason=_one_line(str(error)), unit=task.unit, flights=len(task.recordings))  # fmt: skip
    except (OSError, MemoryError) as error:
        return FleetRow("combined", task.vehicle, paths, sensor=task.sensor, device_id=task.device_id,
                        date=task.dates, verdict="error", codes=_codes_of(error), reason=_one_line(str(error)),
                        unit=task.unit, flights=len(task.recordings))  # fmt: skip
    cal = cal.with_unit(task.unit) if task.unit else cal
    ratio = cal.field_strength / task.model_total if math.isfinite(task.model_total) else math.nan
    return _row("combined", task.vehicle, paths, cal, task.sensor, task.device_id, task.dates, ratio,
                flights=len(task.recordings))  # fmt: skip


def _fit_part_at(index: int, task: _PartTask, settings: _Settings) -> tuple[int, FleetRow]:
    """``(index, _fit_part(task, settings))``: the row with the place of its task, whichever order the tasks end in."""
    return index, _fit_part(task, settings)


#: The methods a combined fit can run (the magnitude-only ones); another (vector, gyro) is combined with als.
_SAMPLES_METHODS = frozenset({"auto", "ellipsoid", "sphere", "minmax", "als", "ml", "diag", "robust"})


def _combine(outcomes: Sequence[_Outcome]) -> tuple[list[_PartTask], list[str]]:
    """The combined fits to run, one per vehicle, compass and part, and the changes found between flights."""
    groups: dict[tuple[str, str, str], list[_Flight]] = {}
    for outcome in outcomes:
        by_sensor = {c.sensor: c for c in outcome.compasses if c.mergeable}
        for row in outcome.rows:
            compass = by_sensor.get(row.sensor)
            if compass is None:
                continue
            key = compass.key or (str(compass.device_id) if compass.device_id is not None else row.sensor)
            groups.setdefault((row.vehicle, key, compass.unit), []).append(_Flight(row, compass))
    tasks: list[_PartTask] = []
    events: list[str] = []
    for (vehicle, _, unit), flights in sorted(groups.items()):
        if len(flights) < 2:
            continue
        flights.sort(key=lambda f: (f.row.date, f.row.path))
        for flight in flights:
            own = _own_fit(flight.compass.statistics)
            flight.own = math.nan if own is None else residual_rms(flight.compass.statistics, own, own_radius=True)
        parts, splits = _split(flights)
        sensor_name = flights[0].row.sensor
        label = f"{vehicle} compass {sensor_name}" if sensor_name else vehicle
        for flight, distance in splits:
            before = parts[next(i for i, p in enumerate(parts) if flight in p.flights) - 1]
            moved = _offset_move(before, flight)
            events.append(
                f"{label}: the flights from {flight.row.date} ({Path(flight.row.path).name}) on do not agree with "
                f"the earlier ones: their samples lie {100 * distance:.2g} % of the field (RMS) further from the "
                f"calibration of both together than from their own{moved}; the vehicle was magnetised, its hardware "
                "or payload changed, or it flew where the Earth's field is not the same: the flights before and "
                "after are combined apart"
            )
        for part in parts:
            if len(part.flights) < 2:
                continue
            ratios = [f.row.field_strength / f.row.field_vs_model for f in part.flights
                      if math.isfinite(f.row.field_vs_model) and f.row.field_vs_model > 0]  # fmt: skip
            first = part.flights[0]
            recorded = tuple((f.row.path, f.row.sensor) for f in part.flights)
            dates = f"{first.row.date}/{part.flights[-1].row.date}"
            model = float(np.median(ratios)) if ratios else math.nan
            tasks.append(_PartTask(vehicle, first.row.sensor, first.compass.device_id, unit, recorded, dates, model))
    return tasks, events


def _offset_move(before: _Part, flight: _Flight) -> str:
    """By how much the offset moved, where the earlier part and the flight each determine one."""
    earlier = [f.row for f in before.flights if f.row.verdict in ("supported", "weak")]
    if not earlier or flight.row.verdict not in ("supported", "weak"):
        return ""
    move = flight.row.offset - earlier[-1].offset
    unit = f" {flight.row.unit}" if flight.row.unit else ""
    shown = ", ".join(f"{value:+.3g}" for value in move)
    return f"; the offset moved by ({shown}){unit} since {earlier[-1].date}"


# ---------------------------------------------------------------------------------------------- engines


#: What a recording's fit imports: a local worker process forks from a server that imported them once, so
#: that no worker pays them (about 1 s each, the first fit's own lazy imports as much again).
PRELOAD = (
    "magfit.fleet", "magfit.pipeline", "magfit.pipeline.motor", "magfit.io.streams", "magfit.geomag",
    "magfit.methods.auto", "magfit.methods.ml", "magfit.methods.als", "magfit.methods.ellipsoid",
    "magfit.sources.read", "magfit.sources.tlog", "magfit.sources.rosbag", "magfit.sources.power",
    "magfit.sources.mavlogdump", "magfit.sources.dataflash", "magfit.sources.ulog", "scipy.special",
    "pyulog", "pygeomag",  # (optional extras: one not installed is passed over)
)  # fmt: skip


class _LocalEngine:
    """Local processes for the whole run (the recordings, then the combined fits).

    ``workers`` processes, forked from a server that imported :data:`PRELOAD` once (``forkserver``; ``spawn``
    where there is none), take the tasks from one queue, each the next as soon as it is free: a long task holds
    up no other, whichever worker has it. (This process took tasks itself before, between handing results on,
    and the pool's workers kept two tasks queued each: on 16 flight logs of which 4 took 2 s each and the rest
    0.05 s, three of the four long ones sat queued behind one worker while this one waited, 16 s of 38.) With
    ``workers=1`` the tasks run in this process, one after the other."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, workers)
        self._pool: Any = None

    def _start(self) -> Any:
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            context: Any
            if "forkserver" in multiprocessing.get_all_start_methods():
                context = multiprocessing.get_context("forkserver")
                context.set_forkserver_preload(list(PRELOAD))
            else:
                context = multiprocessing.get_context("spawn")
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=context)
        return self._pool

    def run(self, function: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[Any]:
        """``function(*task)`` for each task, as they finish (given in the order the workers should take them)."""
        if self.workers <= 1 or len(tasks) <= 1:
            for task in tasks:
                yield function(*task)
            return
        from concurrent.futures import as_completed

        pool = self._start()
        # The pool feeds its workers from one queue, in this order, one task ahead in all: the greedy schedule.
        futures = [pool.submit(function, *task) for task in tasks]
        try:
            for future in as_completed(futures):
                yield future.result()
        finally:
            for future in futures:  # an interrupted run leaves no task to start
                future.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)


def _dask_client(scheduler: Any) -> Any:
    """A client of the Dask cluster at ``scheduler`` (an address or a Client), or an OptionError saying why not."""
    try:
        from distributed import Client
    except ImportError:
        raise OptionError(
            "scheduler= runs the fleet on a Dask cluster, which needs Dask distributed: pip install 'magfit[fleet]'"
        ) from None
    if isinstance(scheduler, Client):
        return scheduler
    try:
        return Client(scheduler, timeout="30s")
    except (OSError, ValueError, TypeError) as error:
        raise OptionError(
            f"--scheduler {scheduler}: no Dask scheduler can be reached there ({_one_line(str(error))}); give its "
            "address as tcp://HOST:PORT"
        ) from None


def _run_dask(function: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], client: Any) -> Iterator[Any]:
    from distributed import as_completed

    if not tasks:
        return
    columns = list(zip(*tasks, strict=True))
    futures = client.map(function, *columns, pure=False)
    for future in as_completed(futures):
        yield future.result()


# ---------------------------------------------------------------------------------------------- the run


def fleet(
    paths: Iterable[str | os.PathLike[str]],
    output: str | os.PathLike[str] | None = None,
    *,
    method: str = "auto",
    field_strength: float | Literal["wmm"] | None = None,
    unit: str | None = None,
    location: tuple[float, float, float] | None = None,
    date: str | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    resume: bool = True,
    combine: bool = True,
    progress: Callable[[int, int, str], None] | None = None,
) -> FleetResult:
    """Calibrate every compass of every recording, and each vehicle's compasses over all its flights.

    Parameters
    ----------
    paths : iterable of str or path-like
        Recordings, folders (walked), globs and ``@LIST`` files (:func:`recordings`).
    output : str or path-like, optional
        The table to write: ``.csv``, ``.parquet`` or ``.jsonl`` (JSON lines), chosen by the extension; its
        journal ``OUTPUT.journal.jsonl`` beside it makes the run resumable. None: nothing is written.
    method : str
        The method for each recording (:func:`magfit.calibrate_file`), and for each vehicle's flights combined
        (their samples fitted together; a vehicle-frame method's combined fit is ``als``).
    field_strength, unit, location, date
        As :func:`magfit.calibrate_file`.
    workers : int, optional
        Local processes (default: the machine's cores), this one among them: 1 runs in this process alone.
    scheduler : str or distributed.Client, optional
        A Dask scheduler's address (``"tcp://host:8786"``) or client: the recordings run on that cluster.
    resume : bool
        Skip the recordings the journal of ``output`` already holds, fitted the same way from the same file (its
        size and modification time; default). A recording that failed runs again. False starts afresh (the old
        journal is replaced, the table rewritten).
    combine : bool
        Also combine each vehicle's flights per compass (default).
    progress : callable, optional
        ``progress(done, total, path)`` after each recording.

    Returns
    -------
    FleetResult
    """
    from .methods import get_method

    get_method(method)
    table = Path(output).resolve() if output is not None else None
    if table is not None:
        _check_table_format(table)
    journal = _journal_path(table) if table is not None else None
    settings = _Settings(method, field_strength, unit, location, date, audience())
    files = [path.resolve() for path in recordings(paths)]  # a cluster's workers do not share our directory
    if table is not None:
        files = [path for path in files if path != table and path != journal]
        for path in files:  # never written over an input (a folder walked finds the table too)
            if table.exists() and os.path.samefile(path, table):
                raise OptionError(f"-o {table} is one of the recordings: give the table another name")
        if not files:
            raise OptionError("no recording left to fit once the table itself is set aside")
    if field_strength == "wmm" and location is None:
        _require_a_place(files)
    root = _common_root(files)
    outcomes: dict[str, _Outcome] = {}
    if journal is not None and journal.exists() and resume:
        outcomes = _read_journal(journal)
    elif journal is not None and journal.exists():
        journal.unlink()
    # A journal entry stands only for the same file fitted the same way, and a recording that failed runs again.
    fresh = {str(p): _fingerprint(p, settings) for p in files}
    outcomes = {k: v for k, v in outcomes.items() if fresh.get(k) == v.fingerprint and not v.failed}
    tasks = [(path, vehicle_of(path, root), settings) for path in files if str(path) not in outcomes]
    tasks.sort(key=lambda task: -_size(task[0]))  # the largest first: the workers end together
    skipped = len(files) - len(tasks)
    client = _dask_client(scheduler) if scheduler is not None else None
    local = _LocalEngine(workers if workers is not None else (os.cpu_count() or 1))

    def run(function: Callable[..., Any], arguments: Sequence[tuple[Any, ...]]) -> Iterator[Any]:
        return _run_dask(function, arguments, client) if client is not None else local.run(function, arguments)

    handle = journal.open("a", encoding="utf-8") if journal is not None else None
    try:
        for done, outcome in enumerate(run(_fit_recording, tasks), start=1):
            outcomes[outcome.path] = outcome
            if handle is not None:
                handle.write(outcome.to_json() + "\n")
                handle.flush()
            if progress is not None:
                progress(done, len(tasks), outcome.path)
        ordered = [outcomes[str(p)] for p in files if str(p) in outcomes]
        flight_rows = [row for outcome in ordered for row in outcome.rows]
        combined: list[FleetRow] = []
        events: list[str] = []
        if combine:
            parts, events = _combine(ordered)
            # Each part (a vehicle's compass over some of its flights) is its own task, matched to its row by its
            # place in ``parts``: the compasses of one vehicle share their flights' paths, never their row.
            largest = sorted(range(len(parts)), key=lambda i: -sum(_size(Path(p)) for p, _ in parts[i].recordings))
            found = dict(run(_fit_part_at, [(index, parts[index], settings) for index in largest]))
            combined = [found[index] for index in range(len(parts))]
    finally:
        local.close()
        if handle is not None:
            handle.close()
        if client is not None and client is not scheduler:
            client.close()
    result = FleetResult(tuple(flight_rows + combined), tuple(events), skipped, table)
    if table is not None:
        write_table(result.rows, table)
    return result


def _require_a_place(files: Sequence[Path]) -> None:
    """``field_strength="wmm"`` without a location: a log's or bag's own GNSS fixes give its place, and a
    recording that has none is a row with code ``no_location``; when no recording is a log or bag, no row
    could have one, and the run is refused at once (one usage error, not a failed row per recording)."""
    from .sources import log_kind

    if any(log_kind(path) is not None for path in files):
        return
    raise OptionError(
        f"{option('field_strength', 'wmm')} needs the place where the recordings were made: give "
        f"{option('location', 'LAT,LON[,ALT]')}; none of the {len(files)} recordings is a flight log or bag with its "
        "own GNSS fixes",
        codes=("no_location",),
    )


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _common_root(files: Sequence[Path]) -> Path:
    """The deepest folder that holds every recording."""
    if not files:
        return Path.cwd()
    return Path(os.path.commonpath([str(path.parent) for path in files]))


def _missing(value: object) -> bool:
    return isinstance(value, float) and not math.isfinite(value)


def _journal_path(table: Path) -> Path:
    return table.with_name(table.name + ".journal.jsonl")


def _read_journal(journal: Path) -> dict[str, _Outcome]:
    """The recordings a journal holds; a line cut by an interrupted run is ignored (that recording runs again)."""
    outcomes: dict[str, _Outcome] = {}
    with journal.open(encoding="utf-8") as handle:
        for line in handle:
            try:
                outcome = _Outcome.from_json(line)
            except (ValueError, KeyError, TypeError, MagfitError):
                continue
            outcomes[outcome.path] = outcome
    return outcomes


_FORMATS = {".csv": "csv", ".parquet": "parquet", ".jsonl": "jsonl", ".ndjson": "jsonl", ".json": "jsonl"}


def _check_table_format(table: Path) -> str:
    kind = _FORMATS.get(table.suffix.lower())
    if kind is None:
        raise OptionError(f"{table}: the table's format is chosen by its extension: .csv, .parquet or .jsonl")
    return kind


def write_table(rows: Sequence[FleetRow], table: str | os.PathLike[str]) -> None:
    """Write the rows as CSV, Parquet or JSON lines (by the extension), atomically (never a half table)."""
    table = Path(table)
    kind = _check_table_format(table)
    columns = FleetRow.columns()
    records = [asdict(row) for row in rows]
    temporary = table.with_name(f".{table.name}.tmp-{os.getpid()}")
    try:
        if kind == "jsonl":
            with temporary.open("w", encoding="utf-8") as handle:
                for record in records:
                    finite = {k: None if _missing(v) else v for k, v in record.items()}
                    handle.write(json.dumps(finite) + "\n")
        else:
            import pandas as pd

            frame = pd.DataFrame.from_records(records, columns=list(columns))
            frame["device_id"] = frame["device_id"].astype("Int64")
            if kind == "csv":
                frame.to_csv(temporary, index=False)
            else:
                try:
                    frame.to_parquet(temporary, index=False)
                except ImportError:
                    raise OptionError(
                        f"{table}: writing Parquet needs pyarrow: pip install 'magfit[fleet]' (or write .csv/.jsonl)"
                    ) from None
        os.replace(temporary, table)
    finally:
        if temporary.exists():
            temporary.unlink()
