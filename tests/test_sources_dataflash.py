"""ArduPilot DataFlash logs: a log written here from a known truth (ArduPilot's calibration applied as
``correct_field`` does), read back, the calibration undone and the truth recovered; the traps told in
words; damaged logs refused in one line."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.errors import DataFileError
from magfit.sources import open_source
from magfit.sources.ardupilot import undo_calibration
from magfit.sources.dataflash import DataFlashLog

HEAD = b"\xa3\x95"
_STRUCT = {
    "Q": "Q",
    "B": "B",
    "h": "h",
    "H": "H",
    "f": "f",
    "I": "I",
    "L": "i",
    "e": "i",
    "N": "16s",
    "Z": "64s",
    "n": "4s",
}


class DataFlashWriter:
    """A minimal DataFlash writer: FMT messages first, then packed messages (the format ArduPilot writes)."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.types: dict[str, tuple[int, str]] = {}
        self.define(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")

    def define(self, type_id: int, name: str, letters: str, labels: str) -> None:
        length = 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in letters))
        self.types[name] = (type_id, letters)
        self.chunks.append(
            HEAD
            + bytes([0x80])
            + struct.pack("<BB4s16s64s", type_id, length, name.encode(), letters.encode(), labels.encode())
        )

    def write(self, name: str, *values: object) -> None:
        type_id, letters = self.types[name]
        encoded = [v.encode() if isinstance(v, str) else v for v in values]
        self.chunks.append(HEAD + bytes([type_id]) + struct.pack("<" + "".join(_STRUCT[c] for c in letters), *encoded))

    def bytes(self) -> bytes:
        return b"".join(self.chunks)


def correct_field(raw: np.ndarray, ofs: np.ndarray, dia: np.ndarray, odi: np.ndarray, scale: float) -> np.ndarray:
    """ArduPilot's correction, written from its description (offset, scale, then the symmetric matrix).

    The firmware applies COMPASS_SCALE only between 0.85 and 1.4, and takes all-zero diagonals as ones.
    """
    dia = dia if np.any(dia) else np.ones(3)
    matrix = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    factor = scale if 0.85 <= scale <= 1.4 else 1.0
    return (factor * (raw + ofs)) @ matrix.T


#: Two compasses: ArduPilot's parameter sets (k = 0, 1) and the raw fields' truth.
COMPASSES = [
    {
        "ofs": np.array([-35.0, 110.5, -80.25]),
        "dia": np.array([1.05, 0.97, 1.02]),
        "odi": np.array([0.03, -0.02, 0.015]),
        "scale": 1.1,
        "dev_id": 97539,
        "soft_iron": np.array([[1.2, 0.1, 0.0], [0.1, 0.9, 0.05], [0.0, 0.05, 1.05]]),
        "hard_iron": np.array([120.0, -60.0, 200.0]),
    },
    {
        "ofs": np.array([12.0, -7.0, 30.0]),
        "dia": np.array([0.0, 0.0, 0.0]),  # all zero: the firmware uses 1
        "odi": np.array([0.0, 0.0, 0.0]),
        "scale": 0.0,  # out of range: not applied
        "dev_id": 658953,
        "soft_iron": np.array([[0.95, 0.0, 0.08], [0.0, 1.1, 0.0], [0.08, 0.0, 1.0]]),
        "hard_iron": np.array([-40.0, 85.0, -150.0]),
    },
]


def _parameters(writer: DataFlashWriter, motct: int = 0, priority: tuple[int, ...] | None = None) -> None:
    for k, compass in enumerate(COMPASSES):
        s = "" if k == 0 else str(k + 1)
        for axis, i in zip("XYZ", range(3), strict=True):
            writer.write("PARM", 1000, f"COMPASS_OFS{s}_{axis}", float(compass["ofs"][i]))
            writer.write("PARM", 1000, f"COMPASS_DIA{s}_{axis}", float(compass["dia"][i]))
            writer.write("PARM", 1000, f"COMPASS_ODI{s}_{axis}", float(compass["odi"][i]))
        writer.write("PARM", 1000, f"COMPASS_SCALE{s}", float(compass["scale"]))
        writer.write("PARM", 1000, f"COMPASS_DEV_ID{s}", float(compass["dev_id"]))
    writer.write("PARM", 1000, "COMPASS_MOTCT", float(motct))
    for slot, device in enumerate(priority or ()):
        writer.write("PARM", 1000, f"COMPASS_PRIO{slot + 1}_ID", float(device))


def _simulations(n: int) -> list[magfit.Simulation]:
    return [
        magfit.simulate(
            n,
            soft_iron=c["soft_iron"],
            hard_iron=c["hard_iron"],
            field_strength=480.0,
            noise=1.5,
            seed=7 + k,
        )
        for k, c in enumerate(COMPASSES)
    ]


def write_new_style(
    path: Path,
    n: int = 1500,
    *,
    motct: int = 0,
    swap_priority: bool = False,
    change: tuple[int, dict[str, np.ndarray], bool] | None = None,
) -> list:
    """MAG with instance field I (ArduPilot 4.x), 20 Hz; returns the simulations (raw truth per compass k).

    ``change``: (j, calibration, logged): from record j on, compass 0 is corrected with ``calibration`` (ofs, dia,
    odi) and its MAG records carry the new offsets; with ``logged`` its PARM messages say so at that time (a
    recalibration), without it they do not (offsets learned in flight and not saved).
    """
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S")
    writer.define(131, "ATT", "Qff", "TimeUS,Roll,Pitch")
    # Slot i of MAG holds compass k = order[i]: the priority list maps them (Compass::_get_state_id).
    order = [1, 0] if swap_priority else [0, 1]
    _parameters(writer, motct, tuple(COMPASSES[k]["dev_id"] for k in order) if swap_priority else None)
    simulations = _simulations(n)
    rng = np.random.default_rng(3)
    motor = rng.uniform(-20, 20, size=(n, 3)) if motct else np.zeros((n, 3))
    motor = np.trunc(motor)  # ArduPilot logs it as int16
    logged = {}
    for k, compass in enumerate(COMPASSES):
        field = correct_field(simulations[k].samples, compass["ofs"], compass["dia"], compass["odi"], compass["scale"])
        logged[k] = np.trunc(field + motor)
    if change is not None:
        start, new, _ = change
        c = {**COMPASSES[0], **new}
        field = correct_field(simulations[0].samples[start:], c["ofs"], c["dia"], c["odi"], c["scale"])
        logged[0][start:] = np.trunc(field + motor[start:])
    for j in range(n):
        time = 2_000_000 + j * 50_000
        if change is not None and j == change[0] and change[2]:
            for name, values in (("OFS", change[1]["ofs"]), ("DIA", change[1]["dia"]), ("ODI", change[1]["odi"])):
                for axis, value in zip("XYZ", values, strict=True):
                    writer.write("PARM", time, f"COMPASS_{name}_{axis}", float(value))
        writer.write("ATT", time, 1.0, 2.0)
        for slot, k in enumerate(order):
            ofs = change[1]["ofs"] if change is not None and k == 0 and j >= change[0] else COMPASSES[k]["ofs"]
            writer.write(
                "MAG", time, slot, *logged[k][j].astype(int), *np.trunc(ofs).astype(int), *motor[j].astype(int), 1, time
            )
    path.write_bytes(writer.bytes())
    return simulations


def write_old_style(path: Path, n: int = 1500, *, motct: int = 0) -> list:
    """MAG and MAG2 without an instance field and without the motor offsets (older ArduPilot)."""
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "Qhhh", "TimeUS,MagX,MagY,MagZ")
    writer.define(131, "MAG2", "Qhhh", "TimeUS,MagX,MagY,MagZ")
    _parameters(writer, motct)
    simulations = _simulations(n)
    for j in range(n):
        for k, name in enumerate(("MAG", "MAG2")):
            c = COMPASSES[k]
            field = correct_field(simulations[k].samples[j : j + 1], c["ofs"], c["dia"], c["odi"], c["scale"])[0]
            writer.write(name, 1_000_000 + j * 100_000, *np.trunc(field).astype(int))
    path.write_bytes(writer.bytes())
    return simulations


def _assert_recovers(calibration: magfit.Calibration, truth: magfit.Calibration) -> None:
    # Noise is 1.5 mG of 480 (0.3 %) plus up to 1 mG of int16 truncation: the identifiable ellipsoid within
    # 1 % of its largest entry and the offset within 1 % of the field still catch any sign or axis mix-up.
    scale = float(np.max(np.abs(truth.ellipsoid_matrix)))
    np.testing.assert_allclose(calibration.ellipsoid_matrix, truth.ellipsoid_matrix, atol=0.01 * scale)
    np.testing.assert_allclose(calibration.offset, truth.offset, atol=0.01 * truth.field_strength)


def test_undo_is_the_inverse_of_correct_field() -> None:
    rng = np.random.default_rng(1)
    raw = rng.normal(0, 400, size=(50, 3))
    c = COMPASSES[0]
    logged = correct_field(raw, c["ofs"], c["dia"], c["odi"], c["scale"])
    back = undo_calibration(logged, offsets=c["ofs"], diagonals=c["dia"], offdiagonals=c["odi"], scale=c["scale"])
    np.testing.assert_allclose(back, raw, atol=1e-9)
    # A scale outside 0.85..1.4 is not applied by the firmware, so it is not undone either.
    plain = correct_field(raw, c["ofs"], c["dia"], c["odi"], 1.0)
    back = undo_calibration(plain, offsets=c["ofs"], diagonals=c["dia"], offdiagonals=c["odi"], scale=2.0)
    np.testing.assert_allclose(back, raw, atol=1e-9)


@pytest.mark.parametrize("swap", [False, True])
def test_new_style_log_recovers_the_raw_field_and_the_truth(tmp_path: Path, swap: bool) -> None:
    path = tmp_path / "00000042.BIN"
    simulations = write_new_style(path, swap_priority=swap)
    source = open_source(path)
    assert source.kind == "dataflash"
    assert [m.id for m in source.magnetometers] == ["MAG/0", "MAG/1"]
    order = [1, 0] if swap else [0, 1]
    for slot, k in enumerate(order):
        magnetometer = source.magnetometers[slot]
        assert magnetometer.device_id == COMPASSES[k]["dev_id"] and magnetometer.unit == "mG"
        assert magnetometer.rate_hz == pytest.approx(20.0)
        read = source.read(magnetometer.id)
        # The raw field comes back to within the int16 truncation of the log (1 mG, divided by the matrix).
        np.testing.assert_allclose(read.samples, simulations[k].samples, atol=1.5)
        _assert_recovers(magfit.fit(read.samples, method="ellipsoid"), simulations[k].truth)
    assert any(other.startswith("ATT (1500)") for other in source.other)


def test_motor_compensation_is_undone_with_the_logged_motor_offsets(tmp_path: Path) -> None:
    path = tmp_path / "motor.bin"
    simulations = write_new_style(path, motct=2)
    read = open_source(path).read("MAG/0")
    assert any("motor compensation" in note for note in read.notes)
    np.testing.assert_allclose(read.samples, simulations[0].samples, atol=1.5)


def test_old_style_log_without_motor_offsets_is_refused_with_the_reason(tmp_path: Path) -> None:
    path = tmp_path / "old.bin"
    write_old_style(path, motct=1)
    source = open_source(path)
    assert [m.id for m in source.magnetometers] == ["MAG/0", "MAG/1"]
    with pytest.raises(DataFileError, match="motor compensation was active"):
        source.read("MAG/1")
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "MAG/0"])
    assert result.exit_code == 2
    assert "COMPASS_MOTCT" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_old_style_log_recovers_the_truth(tmp_path: Path) -> None:
    path = tmp_path / "old.bin"
    simulations = write_old_style(path)
    source = open_source(path)
    for slot in range(2):
        read = source.read(f"MAG/{slot}")
        np.testing.assert_allclose(read.samples, simulations[slot].samples, atol=1.5)


#: A recalibration: compass 0's new offsets and soft-iron matrix.
RECALIBRATED = {
    "ofs": np.array([40.0, -75.0, 12.0]),
    "dia": np.array([0.98, 1.04, 0.99]),
    "odi": np.array([0.01, 0, -0.02]),
}


def test_a_recalibration_half_way_undoes_each_record_with_the_calibration_then_in_effect(tmp_path: Path) -> None:
    # PARM messages change COMPASS_OFS/DIA/ODI at record 700: before, the old calibration; from then, the new.
    path = tmp_path / "recalibrated.bin"
    simulations = write_new_style(path, change=(700, RECALIBRATED, True))
    source = open_source(path)
    magnetometer = source.magnetometer("MAG/0")
    assert magnetometer.problem is None
    assert any("the calibration changed during the log (COMPASS_OFS_X at 37.0 s" in n for n in magnetometer.notes)
    read = source.read("MAG/0")
    np.testing.assert_allclose(read.samples, simulations[0].samples, atol=1.5)
    _assert_recovers(magfit.calibrate_file(path, "ellipsoid", sensor="MAG/0").calibration, simulations[0].truth)
    # Undone with the first calibration throughout, the second half would be tens of mG off: the test can fail.
    c = COMPASSES[0]
    wrong = undo_calibration(
        correct_field(simulations[0].samples[700:], RECALIBRATED["ofs"], RECALIBRATED["dia"], RECALIBRATED["odi"], 1.1),
        offsets=c["ofs"],
        diagonals=c["dia"],
        offdiagonals=c["odi"],
        scale=c["scale"],
    )
    assert np.median(np.linalg.norm(wrong - simulations[0].samples[700:], axis=1)) > 50


def test_offsets_learned_in_flight_are_undone_with_each_records_own(tmp_path: Path) -> None:
    # The offsets change at record 700 without a PARM message (learned and not saved): MAG's OfsX/Y/Z say which.
    path = tmp_path / "learned.bin"
    learned = {"ofs": np.array([-20.0, 95.0, -61.0]), "dia": COMPASSES[0]["dia"], "odi": COMPASSES[0]["odi"]}
    simulations = write_new_style(path, change=(700, learned, False))
    read = open_source(path).read("MAG/0")
    assert any("800 of 1500 records were corrected with offsets that are not" in note for note in read.notes)
    np.testing.assert_allclose(read.samples, simulations[0].samples, atol=1.5)


def test_a_damaged_record_is_skipped_and_counted_not_a_refusal(tmp_path: Path) -> None:
    # One MAG record's offsets and another's time stamp overwritten: each unlike both its neighbours.
    path = tmp_path / "damaged.bin"
    simulations = write_new_style(path)
    data = bytearray(path.read_bytes())
    log = DataFlashLog(path, bytes(data))
    starts = log._offsets[log._by_name["MAG"]]  # the MAG records' byte offsets, slot 0 at even indices
    # MAG payload: TimeUS Q, I B, MagX/Y/Z h, OfsX/Y/Z h ...: OfsX at +3+8+1+6, TimeUS at +3.
    struct.pack_into("<hhh", data, int(starts[2 * 400]) + 18, 5, 13, -18)
    struct.pack_into("<Q", data, int(starts[2 * 900]) + 3, 10**12)
    path.write_bytes(bytes(data))
    read = open_source(path).read("MAG/0")
    assert any("2 of 1500 records skipped as damaged" in note for note in read.notes)
    assert len(read.samples) == 1498
    keep = np.ones(1500, dtype=bool)
    keep[[400, 900]] = False
    np.testing.assert_allclose(read.samples, simulations[0].samples[keep], atol=1.5)
    result = CliRunner().invoke(cli, ["calibrate", str(path), "--sensor", "MAG/0", "-m", "ellipsoid"])
    assert result.exit_code == 0, result.output


def test_records_of_an_unhealthy_compass_are_skipped_and_counted(tmp_path: Path) -> None:
    # MAG's Health 0: AP_Compass logged the last field again (stale). Those records are skipped; a compass
    # unhealthy throughout is refused with that reason.
    path = tmp_path / "unhealthy.bin"
    simulations = write_new_style(path)
    data = bytearray(path.read_bytes())
    log = DataFlashLog(path, bytes(data))
    starts = log._offsets[log._by_name["MAG"]]
    health = 3 + 8 + 1 + 6 * 3  # TimeUS, I, MagX/Y/Z, OfsX/Y/Z, MOX/Y/Z
    for j in range(300, 340):
        data[int(starts[2 * j]) + health] = 0  # compass in slot 0
    for j in range(1500):
        data[int(starts[2 * j + 1]) + health] = 0  # slot 1: unhealthy throughout
    path.write_bytes(bytes(data))
    source = open_source(path)
    read = source.read("MAG/0")
    assert any("40 of 1500 records skipped: the compass was unhealthy (Health 0)" in n for n in read.notes)
    keep = np.ones(1500, dtype=bool)
    keep[300:340] = False
    np.testing.assert_allclose(read.samples, simulations[0].samples[keep], atol=1.5)
    problem = source.magnetometer("MAG/1").problem
    assert problem is not None and "unhealthy (Health 0) in every MAG record" in problem


def test_a_damaged_parm_message_is_skipped_not_a_refusal(tmp_path: Path) -> None:
    # A PARM message whose value is not a number, after the parameter's first: skipped and counted.
    path = tmp_path / "damaged_parm.bin"
    simulations = write_new_style(path)
    data = bytearray(path.read_bytes())
    starts = DataFlashLog(path, bytes(data))._offsets[129]
    # COMPASS_OFS_X's PARM message (TimeUS, Name, Value): a copy of it, its value NaN, inserted after it.
    at = next(int(a) for a in starts if data[a + 11 : a + 27].rstrip(b"\0") == b"COMPASS_OFS_X")
    copy = bytearray(data[at : at + 3 + 8 + 16 + 4])
    struct.pack_into("<f", copy, 3 + 8 + 16, float("nan"))
    path.write_bytes(bytes(data[: at + len(copy)]) + bytes(copy) + bytes(data[at + len(copy) :]))
    source = open_source(path)
    assert "1 PARM messages skipped as damaged (a value that is not a number)" in source.notes
    np.testing.assert_allclose(source.read("MAG/0").samples, simulations[0].samples, atol=1.5)


def test_a_firmware_without_soft_iron_parameters_applied_the_offsets_alone(tmp_path: Path) -> None:
    # ArduCopter 3.2 had COMPASS_OFS but no COMPASS_DIA/ODI (nor SCALE, nor DEV_ID): they are its defaults.
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "Ihhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ")
    c = COMPASSES[0]
    for axis, value in zip("XYZ", c["ofs"], strict=True):
        writer.write("PARM", 500, f"COMPASS_OFS_{axis}", float(value))
    simulation = _simulations(800)[0]
    logged = np.trunc(simulation.samples + c["ofs"])
    for j in range(800):
        writer.write("MAG", 1000 + j * 100, *logged[j].astype(int), *np.trunc(c["ofs"]).astype(int))
    path = tmp_path / "copter32.bin"
    path.write_bytes(writer.bytes())
    (magnetometer,) = open_source(path).magnetometers
    assert magnetometer.problem is None
    assert any(
        "no COMPASS_DIA, COMPASS_ODI parameters, so it applied no soft-iron matrix" in n for n in magnetometer.notes
    )
    read = open_source(path).read("MAG/0")
    np.testing.assert_allclose(read.samples, simulation.samples, atol=1.0)
    # A log whose PARM messages hold no compass parameter at all still cannot say what was applied.
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "Qhhh", "TimeUS,MagX,MagY,MagZ")
    writer.write("PARM", 0, "LOG_BITMASK", 830.0)
    for j in range(100):
        writer.write("MAG", j * 50_000, 100 + j, 0, 300)
    path.write_bytes(writer.bytes())
    (magnetometer,) = open_source(path).magnetometers
    assert magnetometer.problem is not None and "lack COMPASS_OFS_X" in magnetometer.problem


def test_calibrate_on_a_log_fits_each_compass_or_the_chosen_one(tmp_path: Path) -> None:
    path = tmp_path / "flight.bin"
    simulations = write_new_style(path)
    runner = CliRunner()
    # Without --sensor: every compass, one summary each, its first line saying which it is.
    result = runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid"])
    assert result.exit_code == 0, result.output
    blocks = result.stdout.split("\n\n")
    assert len(blocks) == 3 and blocks[2].startswith("ArduPilot tests")  # then the log checks (cli/_consistency.py)
    for k, block in enumerate(blocks[:2]):
        assert (
            f"MAG/{k}: compass {k + 1} (MAG, I={k}), COMPASS_DEV_ID{'' if k == 0 else k + 1} {COMPASSES[k]['dev_id']}"
            in block
        )
        printed = re.search(r"^offset +\(([^)]*)\) mG$", block, re.MULTILINE)
        assert printed is not None
        offset = [float(v) for v in printed.group(1).split(",")]  # the right compass's offset under its name
        np.testing.assert_allclose(offset, simulations[k].truth.offset, atol=0.01 * simulations[k].field_strength)
    # -o with several compasses: one JSON file per compass, named after it (tests/test_pipeline.py has more).
    result = runner.invoke(cli, ["calibrate", str(path), "-m", "ellipsoid", "-o", str(tmp_path / "x.json")])
    assert result.exit_code == 0, result.output
    assert [p.name for p in sorted(tmp_path.glob("x*.json"))] == ["x-MAG_0.json", "x-MAG_1.json"]
    output = tmp_path / "cal.json"
    result = runner.invoke(cli, ["calibrate", str(path), "--sensor", "658953", "-m", "ellipsoid", "-o", str(output)])
    assert result.exit_code == 0, result.output
    calibration = magfit.Calibration.from_json(output.read_text())
    assert calibration.unit == "mG" and calibration.sensor.id == "MAG/1"
    _assert_recovers(calibration, simulations[1].truth)
    assert "ArduPilot DataFlash log; MAG/1" in result.stdout
    assert "after ArduPilot's calibration" in result.stderr  # the trap told in words


def test_inspect_lists_the_compasses(tmp_path: Path) -> None:
    path = tmp_path / "flight.bin"
    write_new_style(path, n=200)
    result = CliRunner().invoke(cli, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    assert "MAG/0  compass 1 (MAG, I=0), COMPASS_DEV_ID 97539: 200 samples in mG" in result.stdout
    assert "20.0 Hz" in result.stdout and "ATT (200)" in result.stdout


def test_a_slow_compass_says_how_to_log_more(tmp_path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "Qhhh", "TimeUS,MagX,MagY,MagZ")
    _parameters(writer)
    for j in range(30):
        writer.write("MAG", j * 1_000_000, 100 + j, 200, 300)
    path = tmp_path / "slow.bin"
    path.write_bytes(writer.bytes())
    (magnetometer,) = open_source(path).magnetometers
    assert any("LOG_BITMASK" in note for note in magnetometer.notes)


@pytest.mark.slow
def test_damaged_and_truncated_logs_fail_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "good.bin"
    write_new_style(path, n=300)
    data = path.read_bytes()
    rng = np.random.default_rng(5)
    runner = CliRunner()
    cases = [data[:cut] for cut in (3, 50, 89, 200, len(data) // 2, len(data) - 7)]
    for _ in range(12):
        damaged = bytearray(data)
        for where in rng.integers(0, len(data), size=int(rng.integers(1, 40))):
            damaged[where] = int(rng.integers(0, 256))
        cases.append(bytes(damaged))
    cases.append(data[:89] + bytes(rng.integers(0, 256, size=5000, dtype=np.uint8)))
    for i, case in enumerate(cases):
        broken = tmp_path / f"broken{i}.bin"
        broken.write_bytes(case)
        for command in (["inspect", str(broken)], ["calibrate", str(broken), "--sensor", "MAG/0", "-m", "ellipsoid"]):
            result = runner.invoke(cli, command)
            assert result.exit_code in (0, 1, 2), (i, command, result.output)
            if result.exit_code:
                lines = result.stderr.strip().splitlines()
                assert lines[-1].startswith("magfit: error: ") and "Traceback" not in result.output, (i, result.output)


#: A cut-down ArduPilot SITL log (ArduCopter 4.x, three compasses; only its FMT, PARM, MAG, ATT, GPS, IMU
#: and VER messages kept), from a public repository under the MIT licence (tests/data/ardupilot_sitl/LICENSE).
SITL = Path(__file__).parent / "data" / "ardupilot_sitl" / "sitl_three_compasses.bin"


def test_real_sitl_log_maps_the_priority_slots_and_refuses_a_still_vehicle() -> None:
    source = open_source(SITL)
    assert [(m.id, m.device_id, m.n_samples) for m in source.magnetometers] == [
        ("MAG/0", 97539, 249),
        ("MAG/1", 131874, 249),
        ("MAG/2", 263178, 249),
    ]
    assert all(m.rate_hz == pytest.approx(10.0, rel=0.01) for m in source.magnetometers)
    read = source.read("MAG/1")
    # COMPASS_OFS2 is (5, 13, -18), DIA2 ones, SCALE2 1: the raw field is the logged one minus the offsets,
    # and its strength is that of SITL's field (495 mG).
    from magfit.sources.dataflash import DataFlashLog

    records = DataFlashLog(SITL, SITL.read_bytes()).messages("MAG")
    logged = records[records["I"] == 1]
    expected = np.column_stack([logged["MagX"], logged["MagY"], logged["MagZ"]]) - [5.0, 13.0, -18.0]
    np.testing.assert_allclose(read.samples, expected)
    assert np.linalg.norm(read.samples[0]) == pytest.approx(495.3, abs=0.1)
    result = CliRunner().invoke(cli, ["calibrate", str(SITL), "--sensor", "MAG/2"])
    assert result.exit_code == 1 and "identical" in result.stderr
    result = CliRunner().invoke(cli, ["calibrate", str(SITL)])  # every compass: each refused, exit 1
    assert result.exit_code == 1 and result.stderr.count("identical") == 3
    assert "3 of 3 magnetometers could not be fitted (MAG/0, MAG/1, MAG/2)" in result.stderr.splitlines()[-1]


def test_a_singular_soft_iron_matrix_is_refused_not_inverted(tmp_path: Path) -> None:
    # Found by the long fuzz run: a damaged COMPASS_DIA_Y of 0 made the undo a singular solve.
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "Qhhh", "TimeUS,MagX,MagY,MagZ")
    for name, value in [("OFS_X", 0.0), ("OFS_Y", 0.0), ("OFS_Z", 0.0), ("DIA_X", 1.0), ("DIA_Y", 0.0), ("DIA_Z", 1.0)]:
        writer.write("PARM", 0, f"COMPASS_{name}", value)
    for axis in "XYZ":
        writer.write("PARM", 0, f"COMPASS_ODI_{axis}", 0.0)
    for j in range(100):
        writer.write("MAG", j * 50_000, 100 + j, 0, 300)
    path = tmp_path / "singular.bin"
    path.write_bytes(writer.bytes())
    (magnetometer,) = open_source(path).magnetometers
    assert magnetometer.problem is not None and "singular matrix" in magnetometer.problem


def test_a_parm_format_without_values_is_one_line(tmp_path: Path) -> None:
    # Found by the long fuzz run: a damaged FMT gave PARM other field names.
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Vxlue")
    writer.write("PARM", 0, "COMPASS_OFS_X", 1.0)
    path = tmp_path / "parm.bin"
    path.write_bytes(writer.bytes())
    with pytest.raises(DataFileError, match="PARM messages' format has no Name and Value"):
        open_source(path)


def test_plot_of_a_refused_log_compass_writes_no_figure(tmp_path: Path) -> None:
    figure = tmp_path / "fit.png"
    result = CliRunner().invoke(cli, ["calibrate", str(SITL), "--sensor", "MAG/0", "--plot", str(figure)])
    assert result.exit_code == 1 and "identical" in result.stderr and not figure.exists()


def test_the_position_is_the_median_of_the_3d_fixes_with_the_gps_time(tmp_path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(132, "GPS", "QBBIHLLe", "TimeUS,I,Status,GMS,GWk,Lat,Lng,Alt")
    writer.write("GPS", 1, 0, 1, 0, 0, 0, 0, 0)
    for j, lat in enumerate((472000000, 472000010, 472000020)):
        writer.write("GPS", 2 + j, 0, 3, 100_000 + j * 200, 2300, lat, 85000000, 48850)
    writer.write("GPS", 9, 1, 3, 100_000, 2300, 100000000, 100000000, 0)  # the second receiver: not used
    path = tmp_path / "gps.bin"
    path.write_bytes(writer.bytes())
    position = open_source(path).position
    assert position is not None and position.n_fixes == 3
    assert position.lat_deg == pytest.approx(47.200001) and position.lon_deg == pytest.approx(8.5)
    assert position.alt_km == pytest.approx(0.4885)
    # GPS week 2300, 100 s into it, less the 18 leap seconds: 2024-02-04 00:01:22 UTC.
    assert position.time_s == pytest.approx(315_964_800 + 2300 * 604_800 + 100 - 18)


def test_the_real_sitl_log_gives_its_position() -> None:
    position = open_source(SITL).position
    assert position is not None and position.n_fixes == 125
    assert (position.lat_deg, position.lon_deg) == pytest.approx((37.2418609, -115.796917))
