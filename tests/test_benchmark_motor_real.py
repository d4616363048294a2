"""benchmarks/motor_real.py's pieces: the scores against a known field, and the copy of an old log whose current
pymavlink's magfit_WMM can read (CURR renamed BAT, Curr in amperes), so the real-log comparison cannot rot."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from test_sources_dataflash import DataFlashWriter

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import motor_real


def _flight(n: int = 400, seed: int = 0) -> motor_real.Flight:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    attitude = Rotation.random(n, random_state=seed).as_matrix()
    field = np.array([230.0, 50.0, -530.0])
    body = np.einsum("nji,j->ni", attitude, field)
    return motor_real.Flight("MAG/0", body, attitude, field, rng.uniform(0, 30, n), {}, 1)


def test_scores_are_zero_on_the_true_field_and_grow_with_an_offset() -> None:
    flight = _flight()
    np.testing.assert_allclose(motor_real.scores(flight.raw, flight), 0.0, atol=1e-9)
    shifted = motor_real.scores(flight.raw + np.array([0.0, 0.0, 20.0]), flight)
    assert 19.0 < shifted[0] < 21.0  # the whole vector: exactly the offset's length
    assert shifted[1] <= shifted[0] + 1e-9  # the yaw recomputed never does worse


def test_a_yaw_error_costs_att_but_not_rp() -> None:
    flight = _flight()
    turn = np.array([[np.cos(0.2), -np.sin(0.2), 0.0], [np.sin(0.2), np.cos(0.2), 0.0], [0.0, 0.0, 1.0]])
    yawed = np.einsum("nji,jk,k->ni", flight.attitude, turn, flight.field_ned)  # the field 11.5 deg off in yaw
    att, rp, magnitude = motor_real.scores(yawed, flight)[:3]
    assert att > 40.0 and rp < 1e-6 and magnitude < 1e-6


def test_the_copy_for_magfit_wmm_renames_curr_to_bat_in_amperes(tmp_path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(129, "CURR", "IhhhHfh", "TimeMS,Throttle,Volt,Curr,Vcc,CurrTot,Volt2")
    writer.write("CURR", 1000, 0, 1654, 2744, 5000, 0.0, 0)
    log = tmp_path / "old.bin"
    log.write_bytes(writer.bytes())
    copy = motor_real._bat_copy(log, tmp_path)
    data = copy.read_bytes()
    assert b"BAT\x00IhhcHfh" in data and b"CURR" not in data
    assert len(data) == len(log.read_bytes())


def _log(records: int) -> bytes:
    writer = DataFlashWriter()
    writer.define(130, "MAG", "QhhhI", "TimeUS,MagX,MagY,MagZ,S")
    writer.define(131, "BAT", "Qf", "TimeUS,Curr")
    for j in range(records):
        writer.write("MAG", 1_000_000 * j, 1, 2, 3, j)
        writer.write("BAT", 1_000_000 * j + 10, float(j))
    return writer.bytes()


def test_the_log_is_cut_before_its_first_mag_record_after_the_time(tmp_path: Path) -> None:
    log = tmp_path / "full.bin"
    log.write_bytes(_log(10))
    assert motor_real.truncated(log, 4.5, tmp_path).read_bytes() == _log(5)


def test_the_logs_head_is_dropped_but_its_formats_and_parameters_are_kept(tmp_path: Path) -> None:
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "QhhhI", "TimeUS,MagX,MagY,MagZ,S")
    writer.define(131, "BAT", "Qf", "TimeUS,Curr")
    writer.write("PARM", 0, "COMPASS_MOTCT", 0.0)
    for j in range(10):
        writer.write("MAG", 1_000_000 * j, 1, 2, 3, j)
        writer.write("BAT", 1_000_000 * j + 10, float(j))
    log = tmp_path / "full.bin"
    log.write_bytes(writer.bytes())
    tail = motor_real.tail_from(log, 6.5, tmp_path)
    messages = motor_real._messages(tail.read_bytes())
    names = [name for _, _, name, _ in messages]
    assert names[:5] == ["FMT"] * 4 + ["PARM"]  # the formats and the parameter, from before the cut
    stamps = [t for _, _, name, t in messages if name == "MAG"]
    assert stamps == [7.0, 8.0, 9.0]  # every MAG record after the cut, none before
    assert names.count("BAT") == 3


def test_the_splits_cut_at_70_percent_of_the_compass_time_span() -> None:
    time_s = np.linspace(10.0, 110.0, 101)
    assert motor_real.Split(head=True).cut_s(time_s) == 80.0
    assert motor_real.Split(head=False).cut_s(time_s) == 40.0
