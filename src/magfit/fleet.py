"""Fleets: many recordings of many vehicles in one run, one table, each vehicle's flights combined.

The data flow, one way:

    paths → recordings (folders, globs, @lists) → per recording, in parallel: calibrate_file's fit and verdict
    for each compass (a "flight" row) and the samples' sufficient statistics → per vehicle and compass: the
    flights in time order, split where they stop agreeing → each part's merged statistics → one fit and verdict
    on the union (a "combined" row)

**Why statistics.** The linear fits read only the scatter ``S = Σ d(z) d(z)ᵀ`` of the design vector
(:mod:`magfit.statistics`), and scatters of different recordings of one sensor add. Several partial flights,
each covering a part of the sphere of directions that determines no calibration alone, merge into one that
does: the verdict is computed on the union (:func:`magfit.diagnostics.diagnose_statistics`).

**Do the flights agree?** Merging is only right while the sensor's distortion stayed the same. A calibration
``(V, M, B)`` is the quadric ``|M (x − V)|² / B² − 1 = 0``; in a recording's canonical frame
``x = s z + c`` it is ``θᵀ d(z)`` with (A = MᵀM / B², the design's √2 on the cross terms)

    θ = (A₁₁, A₂₂, A₃₃, √2 A₁₂, √2 A₁₃, √2 A₂₃) s²,  2 s A (c − V),  (c − V)ᵀ A (c − V) − 1

so the mean squared algebraic residual of a recording against any calibration is ``θᵀ S θ / n`` without its
samples; half its root is the RMS distance to the ellipsoid in units of the field (first order). A flight whose
distance to the calibration of the flights merged with it grows :data:`DISAGREEMENT_RATIO` times beyond its
distance to its own best ellipsoid (and by more than :data:`DISAGREEMENT_FLOOR` of the field) sits on another
ellipsoid: the vehicle was magnetised, or its hardware or payload changed. The flights from it on start a new
part, named with its date and size.

**Where it runs.** Local processes by default (the standard library's process pool: no set-up); a Dask
cluster with ``scheduler="tcp://host:8786"`` (the ``fleet`` extra's ``distributed``). Each recording is one
task; a recording that fails is one row with its reason and never stops the run.

**Resumable.** Every finished recording is appended, with its compasses' statistics, to a journal beside the
table (``TABLE.journal.jsonl``, one JSON line per recording, flushed); a run given the same table skips the
recordings its journal holds, and the table is rewritten (atomically) from the journal at the end.
"""

from __future__ import annotations

import datetime
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
from .errors import MagfitError, OptionError
from .statistics import Statistics

__all__ = [
    "DISAGREEMENT_FLOOR",
    "DISAGREEMENT_RATIO",
    "FleetResult",
    "FleetRow",
    "fleet",
    "recordings",
    "residual_rms",
]

#: A flight disagrees with those merged with it when its distance to their calibration is this many times
#: its distance to its own best ellipsoid ...
DISAGREEMENT_RATIO = 2.0
#: ... and exceeds it by this share of the field (RMS): noise-level differences are not a change.
DISAGREEMENT_FLOOR = 0.01
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
#: The combined fit: a linear method (it reads the merged statistics alone) without the algebraic fit's bias.
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
        The vehicle: the folder that holds the recording (logs that name their vehicle are grouped by it).
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
        The verdict's reason codes (``;``-separated, :data:`magfit.REASON_CODES`) and its words.
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
    """A compass's samples as statistics, with what grouping and merging need (journal only)."""

    sensor: str
    device_id: int | None
    unit: str
    statistics: Statistics
    mergeable: bool


@dataclass(frozen=True)
class _Outcome:
    """What one recording gave: its rows and its compasses' statistics."""

    path: str
    rows: tuple[FleetRow, ...]
    compasses: tuple[_Compass, ...] = ()

    def to_json(self) -> str:
        return json.dumps(
            {
                "path": self.path,
                "rows": [asdict(row) for row in self.rows],
                "compasses": [
                    {
                        "sensor": c.sensor,
                        "device_id": c.device_id,
                        "unit": c.unit,
                        "mergeable": c.mergeable,
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
            _Compass(c["sensor"], c["device_id"], c["unit"], Statistics.from_dict(c["statistics"]), c["mergeable"])
            for c in data["compasses"]
        )
        return cls(data["path"], rows, compasses)


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
            found.update((p, None) for p in recordings(matches))
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
    return name.endswith(RECORDING_SUFFIXES)


def vehicle_of(path: Path) -> str:
    """The vehicle a recording belongs to: the name of the folder that holds it."""
    return path.resolve().parent.name or str(path.resolve().parent)


# ---------------------------------------------------------------------------------------------- one recording


@dataclass(frozen=True)
class _Settings:
    method: str
    field_strength: float | Literal["wmm"] | None
    unit: str | None
    location: tuple[float, float, float] | None
    date: str | None


def _fit_recording(path: Path, vehicle: str, settings: _Settings) -> _Outcome:
    """Every compass of one recording: its row and its statistics; a failure is one row, never an exception."""
    try:
        return _fit_recording_or_raise(path, vehicle, settings)
    except MagfitError as error:
        row = FleetRow("error", vehicle, str(path), date=_file_date(path), method=settings.method,
                       verdict="refused" if error.codes else "error", codes=";".join(error.codes),
                       reason=_one_line(str(error)))  # fmt: skip
        return _Outcome(str(path), (row,), _compasses_anyway(path, settings, error))
    except (OSError, MemoryError) as error:
        return _Outcome(str(path), (FleetRow("error", vehicle, str(path), reason=_one_line(str(error))),))


def _fit_recording_or_raise(path: Path, vehicle: str, settings: _Settings) -> _Outcome:
    from .pipeline import calibrate_file

    result = calibrate_file(
        path, settings.method, unit=settings.unit, field_strength=settings.field_strength,
        location=settings.location, date=settings.date,
    )  # fmt: skip
    statistics = {c.sensor: c for c in _read_compasses(path, settings.unit)}
    rows: list[FleetRow] = []
    compasses: list[_Compass] = []
    for compass in result.compasses:
        cal = compass.calibration
        sensor_info = cal.details.get("sensor") or {}
        sensor = str(sensor_info.get("id") or "")
        device_id = sensor_info.get("device_id")
        model = compass.model_field or result.model_field
        ratio = math.nan
        if model is not None and cal.unit:
            try:
                ratio = cal.field_strength / model.field.total_in(cal.unit)
            except MagfitError:
                ratio = math.nan
        rows.append(_row("flight", vehicle, str(path), cal, sensor, device_id, _log_date(compass, path), ratio))
        read = statistics.get(sensor)
        if read is not None:
            compasses.append(replace_mergeable(read, True, device_id))
    for failure in result.failures:
        codes = failure.codes
        read = statistics.get(failure.sensor)
        rows.append(FleetRow("flight", vehicle, str(path), sensor=failure.sensor,
                             device_id=read.device_id if read is not None else None, date=_file_date(path),
                             method=settings.method, verdict="refused", codes=";".join(codes),
                             reason=_one_line(failure.reason)))  # fmt: skip
        if read is not None:
            compasses.append(replace_mergeable(read, bool(codes) and set(codes) <= PARTIAL_CODES, read.device_id))
    return _Outcome(str(path), tuple(rows), tuple(compasses))


def replace_mergeable(compass: _Compass, mergeable: bool, device_id: int | None) -> _Compass:
    return _Compass(compass.sensor, device_id if device_id is not None else compass.device_id, compass.unit,
                    compass.statistics, mergeable)  # fmt: skip


def _compasses_anyway(path: Path, settings: _Settings, error: MagfitError) -> tuple[_Compass, ...]:
    """A recording refused only for covering too little still gives its statistics to its vehicle's union."""
    if not error.codes or not set(error.codes) <= PARTIAL_CODES:
        return ()
    try:
        return tuple(replace_mergeable(c, True, c.device_id) for c in _read_compasses(path, settings.unit))
    except (MagfitError, OSError, MemoryError):
        return ()


def _read_compasses(path: Path, unit: str | None) -> list[_Compass]:
    """The statistics of each compass of a recording (a log's every usable compass, or a samples file's)."""
    from .sources import log_kind, open_source

    if log_kind(path) is None:
        from .io import iter_sample_chunks

        statistics = Statistics.from_chunks(iter_sample_chunks(path))
        return [_Compass("", None, unit or "", statistics, True)]
    source = open_source(path, everything=False)
    compasses = []
    for magnetometer in source.magnetometers:
        if magnetometer.problem is not None or magnetometer.n_samples == 0:
            continue
        try:
            samples = source.read(magnetometer.id).samples
        except MagfitError:
            continue
        if len(samples) == 0:
            continue
        statistics = Statistics.from_samples(samples)
        compasses.append(_Compass(magnetometer.id, magnetometer.device_id, unit or magnetometer.unit, statistics, True))
    return compasses


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


def _log_date(compass: Any, path: Path) -> str:
    model = getattr(compass, "model_field", None)
    if model is not None and "first at " in model.origin:
        return model.origin.split("first at ", 1)[1].rstrip(")").strip()
    return _file_date(path)


def _file_date(path: Path) -> str:
    try:
        stamp = path.stat().st_mtime
    except OSError:
        return ""
    return datetime.datetime.fromtimestamp(stamp, tz=datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def _one_line(text: str) -> str:
    return " ".join(text.split())


# ---------------------------------------------------------------------------------------------- combining


def residual_rms(statistics: Statistics, calibration: Calibration) -> float:
    """RMS distance of the samples behind ``statistics`` to ``calibration``'s ellipsoid, in units of its field.

    Half the root of ``θᵀ S θ / n`` (module docstring): the first-order distance of the algebraic residual
    ``|M (x − V)|² / B² − 1``, computed from the statistics alone.
    """
    centre, scale = statistics.centre, statistics.scale
    matrix = np.asarray(calibration.matrix)
    a = matrix.T @ matrix / calibration.field_strength**2
    shift = centre - np.asarray(calibration.offset)
    root2 = math.sqrt(2.0)
    theta = np.array([
        a[0, 0] * scale**2, a[1, 1] * scale**2, a[2, 2] * scale**2,
        root2 * a[0, 1] * scale**2, root2 * a[0, 2] * scale**2, root2 * a[1, 2] * scale**2,
        *(2.0 * scale * (a @ shift)),
        float(shift @ a @ shift) - 1.0,
    ])  # fmt: skip
    mean_square = float(theta @ statistics.scatter @ theta) / statistics.n
    return 0.5 * math.sqrt(max(mean_square, 0.0))


def _own_rms(statistics: Statistics) -> float:
    """A flight's distance to its own best ellipsoid (any, determined or not): its noise and model error."""
    from .fit import fit

    try:
        own = fit(statistics, method="ellipsoid", diagnostics=False, allow_undetermined=True)
    except MagfitError:
        return math.nan
    return residual_rms(statistics, own)


def _union_fit(parts: Sequence[Statistics]) -> Calibration | None:
    from .fit import fit

    try:
        return fit(sum(parts, Statistics()), method="ellipsoid", diagnostics=False, allow_undetermined=True)
    except MagfitError:
        return None


@dataclass
class _Flight:
    row: FleetRow
    compass: _Compass
    own: float = math.nan


@dataclass
class _Part:
    flights: list[_Flight] = field(default_factory=list)


def _split(flights: list[_Flight]) -> tuple[list[_Part], list[tuple[_Flight, float, float]]]:
    """The flights in time order, split before each flight that does not agree with those before it.

    Returns the parts and, for each split, the flight that starts it with its distance to the earlier part's
    union and to its own ellipsoid.
    """
    parts = [_Part([flights[0]])]
    splits: list[tuple[_Flight, float, float]] = []
    for flight in flights[1:]:
        current = parts[-1]
        union = _union_fit([f.compass.statistics for f in (*current.flights, flight)])
        if union is None:
            current.flights.append(flight)
            continue
        worst = 0.0
        for member in (*current.flights, flight):
            excess = residual_rms(member.compass.statistics, union)
            own = member.own if np.isfinite(member.own) else 0.0
            if excess > DISAGREEMENT_RATIO * own and excess - own > DISAGREEMENT_FLOOR:
                worst = max(worst, excess)
        if worst > 0.0:
            parts.append(_Part([flight]))
            splits.append((flight, worst, flight.own))
        else:
            current.flights.append(flight)
    return parts, splits


def _combine(outcomes: Sequence[_Outcome]) -> tuple[list[FleetRow], list[str]]:
    """The combined rows of each vehicle and compass, and the changes found between flights."""
    from .fit import fit

    groups: dict[tuple[str, str, str], list[_Flight]] = {}
    for outcome in outcomes:
        by_sensor = {c.sensor: c for c in outcome.compasses if c.mergeable}
        for row in outcome.rows:
            compass = by_sensor.get(row.sensor)
            if compass is None:
                continue
            key = str(compass.device_id) if compass.device_id is not None else row.sensor
            groups.setdefault((row.vehicle, key, compass.unit), []).append(_Flight(row, compass))
    rows: list[FleetRow] = []
    events: list[str] = []
    for (vehicle, key, unit), flights in sorted(groups.items()):
        if len(flights) < 2:
            continue
        flights.sort(key=lambda f: (f.row.date, f.row.path))
        for flight in flights:
            flight.own = _own_rms(flight.compass.statistics)
        parts, splits = _split(flights)
        sensor_name = flights[0].row.sensor or (key if flights[0].compass.device_id is not None else "")
        label = f"{vehicle} compass {sensor_name}" if sensor_name else vehicle
        for flight, distance, own in splits:
            before = parts[next(i for i, p in enumerate(parts) if flight in p.flights) - 1]
            moved = _offset_move(before, flight)
            events.append(
                f"{label}: the flights from {flight.row.date} ({Path(flight.row.path).name}) on do not agree with "
                f"the earlier ones: their samples lie {100 * distance:.1f} % of the field (RMS) off the calibration "
                f"of both together, against {100 * own:.1f} % off their own{moved}; the vehicle was magnetised, or "
                "its hardware or payload changed: the flights before and after are combined apart"
            )
        for part in parts:
            if len(part.flights) < 2:
                continue
            merged = sum((f.compass.statistics for f in part.flights), Statistics())
            paths = ";".join(f.row.path for f in part.flights)
            dates = f"{part.flights[0].row.date}/{part.flights[-1].row.date}"
            sensor = part.flights[0].row.sensor
            device_id = part.flights[0].compass.device_id
            try:
                cal = fit(merged, method=COMBINE_METHOD)
            except MagfitError as error:
                rows.append(FleetRow("combined", vehicle, paths, sensor=sensor, device_id=device_id, date=dates,
                                     method=COMBINE_METHOD, verdict="refused", codes=";".join(error.codes),
                                     reason=_one_line(str(error)), unit=unit, n_samples=merged.n,
                                     flights=len(part.flights)))  # fmt: skip
                continue
            cal = cal.with_unit(unit) if unit else cal
            rows.append(_row("combined", vehicle, paths, cal, sensor, device_id, dates, flights=len(part.flights)))
    return rows, events


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


def _run_local(
    tasks: list[tuple[Path, str]], settings: _Settings, workers: int
) -> Iterator[_Outcome]:
    if workers <= 1 or len(tasks) <= 1:
        for path, vehicle in tasks:
            yield _fit_recording(path, vehicle, settings)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    context = multiprocessing.get_context("forkserver" if "forkserver" in multiprocessing.get_all_start_methods()
                                          else "spawn")  # fmt: skip
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures = [pool.submit(_fit_recording, path, vehicle, settings) for path, vehicle in tasks]
        for future in as_completed(futures):
            yield future.result()


def _run_dask(tasks: list[tuple[Path, str]], settings: _Settings, scheduler: Any) -> Iterator[_Outcome]:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise OptionError(
            "scheduler= runs the fleet on a Dask cluster, which needs Dask distributed: pip install 'magfit[fleet]'"
        ) from None
    client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
    try:
        futures = client.map(_fit_recording, [p for p, _ in tasks], [v for _, v in tasks], [settings] * len(tasks),
                             pure=False)  # fmt: skip
        for future in as_completed(futures):
            yield future.result()
    finally:
        if client is not scheduler:
            client.close()


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
        The method for each recording (:func:`magfit.calibrate_file`); the combined fits use ``als`` on the
        merged statistics.
    field_strength, unit, location, date
        As :func:`magfit.calibrate_file`.
    workers : int, optional
        Local processes (default: the machine's cores); 1 runs in this process.
    scheduler : str or distributed.Client, optional
        A Dask scheduler's address (``"tcp://host:8786"``) or client: the recordings run on that cluster.
    resume : bool
        Skip the recordings the journal of ``output`` already holds (default). False starts afresh (the old
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
    table = Path(output) if output is not None else None
    if table is not None:
        _check_table_format(table)
    journal = _journal_path(table) if table is not None else None
    settings = _Settings(method, field_strength, unit, location, date)
    files = recordings(paths)
    done: dict[str, _Outcome] = {}
    if journal is not None and journal.exists() and resume:
        done = _read_journal(journal)
    elif journal is not None and journal.exists():
        journal.unlink()
    tasks = [(path, vehicle_of(path)) for path in files if str(path) not in done]
    skipped = len(files) - len(tasks)
    engine = _run_dask(tasks, settings, scheduler) if scheduler is not None else _run_local(
        tasks, settings, workers if workers is not None else (os.cpu_count() or 1))  # fmt: skip
    outcomes = dict(done)
    handle = journal.open("a", encoding="utf-8") if journal is not None else None
    try:
        for count, outcome in enumerate(engine, start=1):
            outcomes[outcome.path] = outcome
            if handle is not None:
                handle.write(outcome.to_json() + "\n")
                handle.flush()
            if progress is not None:
                progress(count, len(tasks), outcome.path)
    finally:
        if handle is not None:
            handle.close()
    ordered = [outcomes[str(p)] for p in files if str(p) in outcomes]
    flight_rows = [row for outcome in ordered for row in outcome.rows]
    combined, events = _combine(ordered) if combine else ([], [])
    result = FleetResult(tuple(flight_rows + combined), tuple(events), skipped, table)
    if table is not None:
        write_table(result.rows, table)
    return result


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
