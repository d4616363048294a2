"""Real ArduPilot flight logs end to end (tests/data/ardupilot_real/README.md says where they come from).

A real ArduCopter 3.3-dev flight is read, undone and fitted as it is; then rewritten in memory as the firmware
would have logged it in other circumstances: as ArduCopter 3.2 (no COMPASS_DIA/ODI parameters), with the offsets
changed half-way, with damaged records. The ground truth of each rewrite is the original log's own undone field.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.errors import CalibrationError
from magfit.sources import open_source
from magfit.sources.ardupilot import soft_iron_matrix
from magfit.sources.dataflash import DataFlashLog

DATA = Path(__file__).parent / "data" / "ardupilot_real"
COPTER33 = DATA / "copter33_log171_trimmed.bin"
#: What the firmware applied to compass 1 (COMPASS_OFS/DIA/ODI in the log's PARM messages).
_NAMES = {"MAG/0": ("MAG", ""), "MAG/1": ("MAG2", "2"), "MAG/2": ("MAG3", "3")}


def _records(data: bytes, name: str) -> tuple[np.ndarray, Any, int]:
    """The byte offsets of every ``name`` message, its format and its type id (the reader's own walk)."""
    log = DataFlashLog(Path(name), data)
    type_id = log._by_name[name]
    return log._offsets[type_id], log.formats[type_id], type_id


def _field_at(fmt: Any, label: str) -> int:
    """Where field ``label`` starts in a message (after its 3 header bytes)."""
    assert fmt.dtype is not None
    return 3 + int(fmt.dtype.fields[label][1])


def _parameter(source_bytes: bytes, name: str, path: Path = COPTER33) -> float:
    values = DataFlashLog(path, source_bytes).parameters()[name]
    return values[0][1]


def _matrix(data: bytes, suffix: str) -> np.ndarray:
    return soft_iron_matrix(
        [_parameter(data, f"COMPASS_DIA{suffix}_{a}") for a in "XYZ"],
        [_parameter(data, f"COMPASS_ODI{suffix}_{a}") for a in "XYZ"],
    )


def _rewrite_field(data: bytearray, name: str, rows: np.ndarray, change: Any) -> None:
    """MagX/Y/Z (and with ``change`` returning offsets, OfsX/Y/Z) of records ``rows`` of message ``name``,
    replaced by ``change(logged, offsets) -> (logged, offsets or None)``, as int16 the way the firmware logs."""
    starts, fmt, _ = _records(bytes(data), name)
    for row in rows:
        at = int(starts[row])
        logged = np.array(struct.unpack_from("<hhh", data, at + _field_at(fmt, "MagX")), dtype=float)
        offsets = np.array(struct.unpack_from("<hhh", data, at + _field_at(fmt, "OfsX")), dtype=float)
        new_logged, new_offsets = change(logged, offsets)
        struct.pack_into("<hhh", data, at + _field_at(fmt, "MagX"), *np.rint(new_logged).astype(int))
        if new_offsets is not None:
            struct.pack_into("<hhh", data, at + _field_at(fmt, "OfsX"), *np.rint(new_offsets).astype(int))


def _without_parameters(data: bytes, prefixes: tuple[str, ...]) -> bytes:
    """The log without the PARM messages whose name starts with one of ``prefixes``."""
    starts, fmt, _ = _records(data, "PARM")
    name_at = _field_at(fmt, "Name")
    cut = {int(s) for s in starts if data[s + name_at : s + name_at + 16].rstrip(b"\0").decode().startswith(prefixes)}
    out, pos = bytearray(), 0
    for start in sorted(cut):
        out += data[pos:start]
        pos = start + fmt.length
    return bytes(out + data[pos:])


def _parm_message(data: bytes, name: str, value: float) -> bytes:
    """A PARM message in this log's own format (Name, Value: no time stamp in ArduCopter 3.3)."""
    _, fmt, type_id = _records(data, "PARM")
    assert fmt.labels == ("Name", "Value")
    return b"\xa3\x95" + bytes([type_id]) + struct.pack("<16sf", name.encode(), value)


@pytest.fixture(scope="module")
def original() -> dict[str, np.ndarray]:
    source = open_source(COPTER33)
    return {sensor: source.read(sensor).samples for sensor in ("MAG/0", "MAG/1", "MAG/2")}


COPTER462 = DATA / "copter462_head_80k.bin"


def test_a_real_copter462_log_is_undone_and_refused_only_for_its_four_samples() -> None:
    # ArduCopter 4.6.2: MAG instances mapped through COMPASS_PRIOn_ID, compass 2 with an onboard calibration's
    # DIA2/ODI2. The truth: the records themselves, corrected again as the firmware does.
    source = open_source(COPTER462)
    assert [(m.id, m.device_id, m.problem) for m in source.magnetometers] == [
        ("MAG/0", 592905, None),
        ("MAG/1", 658945, None),
    ]
    data = COPTER462.read_bytes()
    records = DataFlashLog(COPTER462, data).messages("MAG")
    for slot, suffix in ((0, ""), (1, "2")):
        read = source.read(f"MAG/{slot}")
        mine = records[records["I"] == slot]
        logged = np.column_stack([mine[axis].astype(float) for axis in ("MagX", "MagY", "MagZ")])
        offsets = np.array([_parameter(data, f"COMPASS_OFS{suffix}_{a}", COPTER462) for a in "XYZ"])
        matrix = soft_iron_matrix(
            [_parameter(data, f"COMPASS_DIA{suffix}_{a}", COPTER462) for a in "XYZ"],
            [_parameter(data, f"COMPASS_ODI{suffix}_{a}", COPTER462) for a in "XYZ"],
        )
        np.testing.assert_allclose((read.samples + offsets) @ matrix.T, logged, atol=1e-3)
    result = CliRunner().invoke(cli, ["calibrate", str(COPTER462)])
    assert result.exit_code == 1 and "needs at least" in result.stderr and "got 4" in result.stderr
    assert "log the parameters" not in result.output and "Traceback" not in result.output


def test_a_real_tlog_is_undone_with_the_fetched_parameters_and_refused_for_its_few_directions() -> None:
    # The ground station fetched the whole parameter list: both compasses undone with it (the same logic as a
    # .bin's PARM messages); 27 samples at 1.2 Hz on the ground determine no model: exit 1, with that reason.
    path = DATA / "fs_batt_2016.tlog"
    source = open_source(path)
    assert [(m.id, m.device_id, m.problem) for m in source.magnetometers] == [
        ("RAW_IMU", 73225, None),
        ("SCALED_IMU2", 131594, None),
    ]
    assert all(any("undone with COMPASS_OFS" in note for note in m.notes) for m in source.magnetometers)
    result = CliRunner().invoke(cli, ["calibrate", str(path)])
    assert result.exit_code == 1 and result.stderr.count("the samples determine no calibration model") == 2
    assert "log the parameters" not in result.output and "lack" not in result.output


def test_a_real_copter33_flight_undoes_every_compass_to_what_the_firmware_logged() -> None:
    source = open_source(COPTER33)
    assert [m.id for m in source.magnetometers] == ["MAG/0", "MAG/1", "MAG/2"]
    assert all(m.problem is None for m in source.magnetometers)
    assert source.position is not None and source.position.lat_deg == pytest.approx(-35.362, abs=1e-3)
    # Its GPS logs the week and the time of week as Week and TimeMS (before 3.4): the model's date is the flight's.
    assert 2015.8 < 1970 + source.position.time_s / (365.25 * 86400) < 2016.0
    data = COPTER33.read_bytes()
    for sensor, (name, suffix) in _NAMES.items():
        read = source.read(sensor)
        assert len(read.samples) == source.magnetometer(sensor).n_samples  # nothing skipped in a sound log
        # The truth: the records themselves. The raw field, corrected again as the firmware does
        # (M · (raw + ofs)), gives back MagX/Y/Z to the int16 truncation.
        starts, fmt, _ = _records(data, name)
        logged = np.array(
            [struct.unpack_from("<hhh", data, int(s) + _field_at(fmt, "MagX")) for s in starts], dtype=float
        )
        offsets = np.array([_parameter(data, f"COMPASS_OFS{suffix}_{a}") for a in "XYZ"])
        again = (read.samples + offsets) @ _matrix(data, suffix).T
        np.testing.assert_allclose(again, logged, atol=1e-3)


@pytest.mark.slow
def test_the_real_flight_calibrates_end_to_end(original: dict[str, np.ndarray]) -> None:
    result = CliRunner().invoke(cli, ["calibrate", str(COPTER33)])
    # From the field's magnitude alone, a flight's few directions leave a distortion that a richer model sees on
    # held-out stretches (±11° and ±54° of heading on compasses 1 and 2): each compass is refused with its reason
    # and code (compass 3, uncalibrated and unhealthy in this vehicle, lies on no ellipsoid): exit 1, every compass
    # read and judged.
    assert result.exit_code == 1, result.output
    assert all(f"MAG/{i}: not fitted" in result.stdout for i in range(3))
    assert "log the parameters" not in result.output and "Traceback" not in result.output
    fitted = magfit.calibrate_file(COPTER33)
    assert {failure.sensor for failure in fitted.failures} == {"MAG/0", "MAG/1", "MAG/2"}
    assert all(failure.codes for failure in fitted.failures)


def test_the_refused_compass_of_the_real_flight_says_why_with_a_code(original: dict[str, np.ndarray]) -> None:
    with pytest.raises(CalibrationError) as refused:
        magfit.fit(original["MAG/2"], method="auto")
    assert refused.value.codes and "unclassified" not in refused.value.codes


@pytest.mark.slow
def test_as_copter32_logged_it_the_missing_soft_iron_parameters_are_the_identity(
    tmp_path: Path, original: dict[str, np.ndarray]
) -> None:
    # ArduCopter 3.2 had no COMPASS_DIA/ODI: its PARM messages lack them and its MAG records are the field with
    # the offsets alone, M⁻¹ · logged. Before, such a log was refused ("... lack COMPASS_DIA_X ... log the
    # parameters"), a remedy the firmware could not follow.
    data = bytearray(_without_parameters(COPTER33.read_bytes(), ("COMPASS_DIA", "COMPASS_ODI")))
    for sensor, (name, suffix) in _NAMES.items():
        inverse = np.linalg.inv(_matrix(COPTER33.read_bytes(), suffix))
        _rewrite_field(data, name, np.arange(len(original[sensor])), lambda logged, _, m=inverse: (m @ logged, None))
    path = tmp_path / "copter32.bin"
    path.write_bytes(bytes(data))
    source = open_source(path)
    for sensor in _NAMES:
        magnetometer = source.magnetometer(sensor)
        assert magnetometer.problem is None
        assert any("applied no soft-iron matrix" in note for note in magnetometer.notes)
        np.testing.assert_allclose(source.read(sensor).samples, original[sensor], atol=1.0)
    # The flight alone determines no calibration from the field's magnitude (test above): forced, the same one.
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "MAG/1", "--force"])
    assert result.exit_code == 0, result.output
    assert "has no COMPASS_DIA2, COMPASS_ODI2 parameters" in result.stderr
    refit = magfit.calibrate_file(path, sensor="MAG/1", force=True).calibration
    first = magfit.calibrate_file(COPTER33, sensor="MAG/1", force=True).calibration
    np.testing.assert_allclose(refit.offset, first.offset, atol=3.0)


#: The offsets a recalibration (or learning) moved compass 1's to, from record 1192 on: mG, whole.
SHIFT = np.array([37.0, -52.0, 24.0])


@pytest.mark.slow
def test_offsets_changed_half_way_are_undone_record_by_record(tmp_path: Path, original: dict[str, np.ndarray]) -> None:
    # From the middle on, compass 1 is corrected with offsets SHIFT mG larger: its records log the field
    # M · (raw + ofs + SHIFT) and OfsX/Y/Z + SHIFT, and PARM messages (without a time, as 3.3 writes them) say
    # COMPASS_OFS changed. Before, this was refused ("fit a log recorded after the change").
    source_bytes = COPTER33.read_bytes()
    data = bytearray(source_bytes)
    middle = len(original["MAG/0"]) // 2
    matrix = _matrix(source_bytes, "")
    _rewrite_field(
        data,
        "MAG",
        np.arange(middle, len(original["MAG/0"])),
        lambda logged, ofs: (logged + matrix @ SHIFT, ofs + SHIFT),
    )
    starts, _, _ = _records(bytes(data), "MAG")
    at = int(starts[middle])
    offsets = [_parameter(source_bytes, f"COMPASS_OFS_{a}") for a in "XYZ"]
    inserted = b"".join(
        _parm_message(source_bytes, f"COMPASS_OFS_{a}", o + d) for a, o, d in zip("XYZ", offsets, SHIFT, strict=True)
    )
    path = tmp_path / "recalibrated.bin"
    path.write_bytes(bytes(data[:at]) + inserted + bytes(data[at:]))
    source = open_source(path)
    magnetometer = source.magnetometer("MAG/0")
    assert magnetometer.problem is None
    assert any("the calibration changed during the log (COMPASS_OFS_X (no time)" in n for n in magnetometer.notes)
    read = source.read("MAG/0")
    changed = len(original["MAG/0"]) - middle
    assert any(f"{changed} of {len(original['MAG/0'])} records were corrected with offsets" in n for n in read.notes)
    # The records' own offsets are whole mG: the raw field within the original's by that truncation and the
    # rounding of the rewritten field.
    np.testing.assert_allclose(read.samples, original["MAG/0"], atol=2.0)
    refit = magfit.calibrate_file(path, sensor="MAG/0", force=True).calibration
    first = magfit.calibrate_file(COPTER33, sensor="MAG/0", force=True).calibration
    np.testing.assert_allclose(refit.offset, first.offset, atol=3.0)
    # Undone with the first offsets throughout, the second half would be SHIFT off: the test can fail.
    assert np.linalg.norm(SHIFT) > 30


@pytest.mark.slow
def test_damaged_records_in_the_real_flight_are_skipped_and_counted(
    tmp_path: Path, original: dict[str, np.ndarray]
) -> None:
    # One record's offsets and another's time stamp overwritten. Before, the first refused the whole compass
    # with a message that contradicted itself (the first record's offsets shown as the mismatch).
    data = bytearray(COPTER33.read_bytes())
    starts, fmt, _ = _records(bytes(data), "MAG")
    struct.pack_into("<hhh", data, int(starts[1000]) + _field_at(fmt, "OfsX"), 5, 13, -18)
    struct.pack_into("<I", data, int(starts[1500]) + _field_at(fmt, "TimeMS"), 4_000_000_000)
    path = tmp_path / "damaged.bin"
    path.write_bytes(bytes(data))
    read = open_source(path).read("MAG/0")
    assert any(f"2 of {len(original['MAG/0'])} records skipped as damaged" in note for note in read.notes)
    keep = np.ones(len(original["MAG/0"]), dtype=bool)
    keep[[1000, 1500]] = False
    np.testing.assert_allclose(read.samples, original["MAG/0"][keep], atol=1e-9)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "MAG/0", "--force"])
    assert result.exit_code == 0, result.output
    assert "2 of 2384 records skipped as damaged" in result.stderr


def _half(data: bytes, name: str, which: int) -> bytes:
    """The log with compass message ``name``'s first (0) or second (1) half of its time span: the compass and
    motion messages (MAG*, ATT, IMU, AHR2, XKQ) outside that half are dropped, every other message kept."""
    log = DataFlashLog(COPTER33, data)
    own = log.messages(name)
    label, factor = ("TimeUS", 1e-6) if "TimeUS" in (own.dtype.names or ()) else ("TimeMS", 1e-3)
    times = own[label].astype(float) * factor
    middle = (times.min() + times.max()) / 2
    keep: list[int] = []
    for type_id, starts in log._offsets.items():
        fmt = log.formats[type_id]
        timed = next((lab for lab in ("TimeUS", "TimeMS") if lab in fmt.labels), None)
        if fmt.name not in ("MAG", "MAG2", "MAG3", "ATT", "IMU", "AHR2", "XKQ") or timed is None:
            keep.extend(int(s) for s in starts)
            continue
        stamps = log.messages(fmt.name)[timed].astype(float) * (1e-6 if timed == "TimeUS" else 1e-3)
        inside = stamps < middle if which == 0 else stamps >= middle
        keep.extend(int(s) for s in starts[inside])
    length = {type_id: fmt.length for type_id, fmt in log.formats.items()}
    return b"".join(data[s : s + length[data[s + 2]]] for s in sorted(keep))


#: Offsets of the two halves this far apart, in combined stated one-sigmas, must be named (issue: honest
#: uncertainty on real logs).
HALVES_SIGMAS = 3.5


def _halves_apart(tmp_path: Path, sensor: str, method: str, force: bool) -> float | None:
    """How many combined stated one-sigmas the offsets of the flight's two halves lie apart (the largest axis);
    None when a half states none (refused, unforced: nothing stated, nothing to contradict)."""
    data = COPTER33.read_bytes()
    name = _NAMES[sensor][0]
    fits = []
    for which in (0, 1):
        path = tmp_path / f"half{which}.bin"
        path.write_bytes(_half(data, name, which))
        try:
            fits.append(magfit.calibrate_file(path, method, sensor=sensor, force=force).calibration)
        except CalibrationError:
            return None
    sigmas = [c.diagnostics.uncertainty.offset_sigma if c.diagnostics and c.diagnostics.uncertainty else None
              for c in fits]  # fmt: skip
    if sigmas[0] is None or sigmas[1] is None:
        return None
    combined = np.hypot(np.asarray(sigmas[0]), np.asarray(sigmas[1]))
    return float(np.max(np.abs(np.asarray(fits[0].offset) - np.asarray(fits[1].offset)) / combined))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("sensor", "method"),
    [
        ("MAG/0", "auto"),
        # Compass 2's halves were two weak spheres 26.6 combined one-sigmas apart on z (offsets (-172, -118, +351) mG
        # apart, each stating 6-27 mG): each half's heading bound is now beyond use, and both are refused.
        ("MAG/1", "auto"),
        ("MAG/0", "vector"),
        ("MAG/1", "vector"),
    ],
)
def test_the_halves_of_a_real_flight_agree_or_the_disagreement_is_named(
    tmp_path: Path, sensor: str, method: str
) -> None:
    apart = _halves_apart(tmp_path, sensor, method, force=False)
    if apart is None or apart <= HALVES_SIGMAS:
        return
    try:
        whole = magfit.calibrate_file(COPTER33, method, sensor=sensor).calibration
    except CalibrationError as refused:
        assert "inconsistent_halves" in refused.codes, f"halves {apart:.1f} sigmas apart, refused for: {refused}"
        return
    support = whole.support.to_dict()
    named = [*support["refusal_codes"], *support["weakness_codes"]]
    assert "inconsistent_halves" in named, f"halves {apart:.1f} sigmas apart; the whole log's fit names {named}"


@pytest.mark.slow
@pytest.mark.parametrize(("sensor", "method"), [("MAG/1", "auto"), ("MAG/1", "sphere"), ("MAG/0", "auto")])
def test_forced_the_halves_of_a_real_flight_agree_or_the_forced_output_names_the_disagreement(
    tmp_path: Path, sensor: str, method: str
) -> None:
    # Forced (--force), every half states numbers, and so does the whole log. Compass 2's halves under auto are
    # 18 combined one-sigmas apart (the first half weak, the second forced); the whole log's forced output named
    # only `undetermined`, `large_residual` and `low_coverage`: auto's choice never had its halves compared.
    apart = _halves_apart(tmp_path, sensor, method, force=True)
    assert apart is not None
    whole = magfit.calibrate_file(COPTER33, method, sensor=sensor, force=True).calibration
    assert whole.support is not None
    named = list(whole.support.codes)
    assert apart <= HALVES_SIGMAS or "inconsistent_halves" in named, (apart, named)
    if sensor == "MAG/1":  # the case that must be named (a test that can fail)
        # Each half's offset one-sigma now carries the known biases its heading one-sigma carries (the richer
        # model's distance, diagnostics eq. C), which covers most of their disagreement (1.2 combined one-sigmas
        # apart, was 18); the whole log's own halves, compared on its stride, still name it.
        assert "inconsistent_halves" in named, (apart, named)
