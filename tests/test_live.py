"""magfit.live's parts: the line parser, MotionCal's packet, the simulated board, the session's verdict."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

import magfit
from magfit.errors import DataFileError, ExportError
from magfit.live import LineParser, Session, SimulatedBoard, Thresholds, crc16, motioncal_packet
from magfit.live.session import FitResult

# ---------------------------------------------------------------------- the parser


def test_raw_lines_are_tenths_of_microtesla() -> None:
    parser = LineParser()
    samples = parser.feed(b"Raw:1,2,8192,-3,4,5,123,-456,789\r\nRaw:0,0,0,0,0,0,-32768,32767,0\r\n")
    np.testing.assert_allclose(samples, [[12.3, -45.6, 78.9], [-3276.8, 3276.7, 0.0]])
    assert parser.unit == "uT" and parser.dialect == "Raw"
    assert parser.counts.samples == 2 and parser.counts.junk == 0


@pytest.mark.parametrize(
    "line",
    [
        b"Raw:1,2,3,4,5,6,7,8\r\n",  # eight values (MotionCal: exactly nine)
        b"Raw:1,2,3,4,5,6,7,8,9,10\r\n",  # ten
        b"Raw:1,2,3,4,5,6,7.5,8,9\r\n",  # a float: Raw: carries integers
        b"Raw:1,2,3,4,5,6,7,8,40000\r\n",  # beyond int16
        b"Raw:1,2,3,4,5,6,7,,9\r\n",  # an empty field
    ],
)
def test_malformed_raw_lines_are_junk(line: bytes) -> None:
    parser = LineParser()
    assert parser.feed(b"Raw:0,0,0,0,0,0,1,2,3\r\n" + line + b"Raw:0,0,0,0,0,0,4,5,6\r\n").tolist() == [
        [0.1, 0.2, 0.30000000000000004],
        [0.4, 0.5, 0.6000000000000001],
    ]
    assert parser.counts.junk == 1 and parser.counts.interruptions == 1


def test_uni_lines_and_raw_uni_pairs_count_once() -> None:
    parser = LineParser()
    assert parser.feed(b"Uni:0.1,0.2,9.8,0.0010,0,0,12.34,-5.5,40.25\n").tolist() == [[12.34, -5.5, 40.25]]
    # Adafruit's sketches print each sample as a Raw: line then a Uni: line: only the first tag seen counts.
    both = LineParser()
    text = b"".join(b"Raw:0,0,0,0,0,0,%d,0,0\r\nUni:0,0,0,0,0,0,%d.0,0,0\r\n" % (10 * i, i) for i in range(1, 6))
    np.testing.assert_allclose(both.feed(text)[:, 0], [1.0, 2.0, 3.0, 4.0, 5.0])
    assert both.counts.other_tag == 5 and both.counts.junk == 0


def test_any_cut_of_the_bytes_gives_the_same_samples() -> None:
    board = SimulatedBoard(seed=4)
    data = board.raw_lines(200).replace(b"\r\n", b"\n", 50).replace(b"\r\n", b"\r", 50)  # LF, CR and CR LF ends
    whole = LineParser().feed(data)
    one_byte = LineParser()
    pieces = [one_byte.feed(data[i : i + 1]) for i in range(len(data))]
    np.testing.assert_array_equal(np.concatenate(pieces), whole)
    assert whole.shape == (200, 3)


def test_reset_noise_reboot_and_a_cut_first_line() -> None:
    parser = LineParser(first_line_may_be_cut=True)
    stream = (
        b"0,-3,120,-45,12\r\n"  # the tail of a line printed before the port was opened
        b"Raw:0,0,0,0,0,0,10,20,30\r\n"
        b"\x00\xff\xfe\x13 garbage\r\n"  # noise on the line
        b"Raw:0,0,0,0,0,0,11,21,31\r\n"
        b"Raw:0,0,0,0,0,0,12,2"  # a reboot cuts this line ...
        b"\x00\xf8Adafruit AHRS calibration\r\nFXOS8700 found\r\n"  # ... and the banner follows
        b"\x87\x01Raw:0,0,0,0,0,0,13,23,33\r\n"  # noise before a tag: read from the tag
    )
    samples = parser.feed(stream)
    np.testing.assert_allclose(samples[:, 0], [1.0, 1.1, 1.3])
    assert parser.counts.dropped_first
    assert parser.counts.junk == 3 and parser.counts.interruptions == 2


def test_calibration_echo_lines_are_kept() -> None:
    parser = LineParser()
    parser.feed(b"Cal1:0.000,0.000,0.000,0.000,0.000,0.000,12.500,-30.200,21.700,48.000\r\n")
    parser.feed(b"Cal2:0.9486,-0.0485,0.0000,-0.0485,1.0300,0.0000,0.0000,0.0000,1.0204\r\n")
    assert parser.cal1 is not None and parser.cal1[6:] == (12.5, -30.2, 21.7, 48.0)
    assert parser.cal2 is not None and len(parser.cal2) == 9
    assert parser.counts.samples == 0 and parser.dialect is None


def test_plain_lines_find_the_magnetometer_columns_by_name() -> None:
    parser = LineParser()
    text = b"t,ax,ay,az,mx,my,mz\n0.0,0.1,0.2,9.8,10,20,30\n0.1,0.1,0.2,9.8,11,21,31\n0.2,1,2\n"
    assert parser.feed(text).tolist() == [[10, 20, 30], [11, 21, 31]]
    assert parser.column_names == ("mx", "my", "mz") and parser.unit is None
    assert parser.counts.junk == 1  # the short line (cut by a reset) is not a sample


def test_plain_lines_without_a_header_and_with_columns() -> None:
    assert LineParser().feed(b"1 2 3 4\n5 6 7 8\n").tolist() == [[1, 2, 3], [5, 6, 7]]
    assert LineParser(columns=[3, 2, 1]).feed(b"1;2;3;4\n").tolist() == [[4, 3, 2]]
    assert LineParser(columns=["Bz", "By", "Bx"]).feed(b"Bx,By,Bz\n1,2,3\n").tolist() == [[3, 2, 1]]
    # Once the stream is plain, a tagged line is not a sample (and the reverse).
    parser = LineParser()
    parser.feed(b"1,2,3\nRaw:0,0,0,0,0,0,1,2,3\r\n")
    assert parser.counts.samples == 1 and parser.counts.junk == 1


def test_a_header_with_two_magnetometers_is_an_error_naming_them() -> None:
    with pytest.raises(DataFileError, match="imu_mx,imu_my,imu_mz.*mag_x,mag_y,mag_z.*--columns"):
        LineParser().feed(b"imu_mx,imu_my,imu_mz,mag_x,mag_y,mag_z\n1,2,3,4,5,6\n")


# ---------------------------------------------------------------------- the packet


def test_crc16_is_crc16_modbus() -> None:
    assert crc16(b"123456789") == 0x4B37  # the catalogued check value of CRC-16/MODBUS
    assert crc16(b"") == 0xFFFF


def adafruit_receive(stream: bytes) -> list[dict[str, object]]:
    """The receiving side of Adafruit's calibration sketches (receiveCalibration), byte by byte, re-implemented.

    Signature 117, 84; 68 bytes; CRC-16 (0xA001, start 0xFFFF) over all 68 must be 0; 16 little-endian
    floats from byte 2: accel[3], gyro[3], mag_hardiron[3], mag_field, then the soft-iron matrix from
    offsets [10] [13] [14] / [13] [11] [15] / [14] [15] [12].
    """

    def update(crc: int, byte: int) -> int:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        return crc

    stored: list[dict[str, object]] = []
    buffer: list[int] = []
    for byte in stream:
        if not buffer and byte != 117:
            continue
        if len(buffer) == 1 and byte != 84:
            buffer = []
            continue
        buffer.append(byte)
        if len(buffer) < 68:
            continue
        crc = 0xFFFF
        for b in buffer:
            crc = update(crc, b)
        if crc == 0:
            offsets = struct.unpack("<16f", bytes(buffer[2:66]))
            softiron = [offsets[i] for i in (10, 13, 14, 13, 11, 15, 14, 15, 12)]
            stored.append(
                {
                    "hardiron": offsets[6:9],
                    "field": offsets[9],
                    "softiron": np.array(softiron).reshape(3, 3),
                    "zero": offsets[:6],
                }
            )
        buffer = []
    return stored


def test_packet_is_what_the_adafruit_receiver_accepts() -> None:
    sim = magfit.scenario("mpu9250", "smartphone").simulate(3000, seed=2)
    cal = magfit.fit(sim.samples * 0.15, "ellipsoid").with_unit("uT")  # counts of 0.15 µT, as the MPU-9250
    packet = motioncal_packet(cal)
    assert len(packet) == 68 and packet[:2] == b"uT"  # 117, 84
    # Byte for byte: signature, 16 little-endian float32, CRC LSB first, built here without magfit's code.
    m = cal.matrix
    values = [0, 0, 0, 0, 0, 0, *cal.offset, cal.field_strength, m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]]
    body = bytes([117, 84]) + b"".join(struct.pack("<f", v) for v in values)
    assert packet[:66] == body
    (stored,) = adafruit_receive(b"noise" + packet + b"Raw:")
    np.testing.assert_allclose(stored["hardiron"], cal.offset, rtol=1e-6)
    np.testing.assert_allclose(stored["field"], cal.field_strength, rtol=1e-6)
    np.testing.assert_allclose(stored["softiron"], cal.matrix, rtol=1e-6, atol=1e-7)
    assert stored["zero"] == (0.0,) * 6
    # The firmware's formula on the stored numbers equals magfit's correction.
    raw = sim.samples[:50] * 0.15
    firmware = (raw - np.asarray(stored["hardiron"])) @ np.asarray(stored["softiron"]).T
    np.testing.assert_allclose(firmware, cal.apply(raw), atol=1e-4)


def test_a_damaged_packet_is_refused_by_the_receiver() -> None:
    packet = bytearray(motioncal_packet(magfit.Calibration("x", [1, 2, 3], np.eye(3), 50.0, unit="uT")))
    packet[30] ^= 0x01
    assert adafruit_receive(bytes(packet)) == []


def test_packet_units_and_refusals() -> None:
    in_nt = magfit.Calibration("x", [1000.0, -2000.0, 500.0], np.eye(3), 48000.0, unit="nT")
    (stored,) = adafruit_receive(motioncal_packet(in_nt))
    np.testing.assert_allclose(stored["hardiron"], [1.0, -2.0, 0.5])
    assert math.isclose(float(stored["field"]), 48.0, rel_tol=1e-7)  # type: ignore[arg-type]
    with pytest.raises(ExportError, match="unit is unknown.*--unit"):
        motioncal_packet(magfit.Calibration("x", [0, 0, 0], np.eye(3), 1.0))
    with pytest.raises(ExportError, match="raw counts"):
        motioncal_packet(magfit.Calibration("x", [0, 0, 0], np.eye(3), 1.0, unit="counts"))
    skew = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ExportError, match="not symmetric"):
        motioncal_packet(magfit.Calibration("x", [0, 0, 0], skew, 50.0, unit="uT"))


# ---------------------------------------------------------------------- board and session


def test_simulated_board_follows_its_truth() -> None:
    board = SimulatedBoard(seed=5)
    mag, accel, gyro = board.readings(3000)
    truth = board.truth.calibration
    radius = np.linalg.norm(truth.apply(mag), axis=1)
    assert abs(np.median(radius) - truth.field_strength) < 0.05
    np.testing.assert_allclose(np.linalg.norm(accel, axis=1), 1.0, atol=1e-9)
    steps = np.degrees(np.arccos(np.clip(np.sum(mag[1:] * mag[:-1], axis=1) / np.prod(
        np.linalg.norm([mag[1:], mag[:-1]], axis=2), axis=0), -1, 1)))  # fmt: skip
    assert np.median(steps) < 5.0  # successive samples are close: a hand, not a random draw
    assert 30 < np.median(np.linalg.norm(gyro, axis=1)) < 300  # degrees per second


def test_session_fits_an_even_subset_and_judges_it() -> None:
    board = SimulatedBoard(rate_hz=100, seed=6)
    session = Session(thresholds=Thresholds(min_coverage=0.8, max_heading_sigma_deg=1.0), fit_samples=1000)
    parser = LineParser()
    for _ in range(60):
        session.add(parser.feed(board.raw_lines(100)))
    result = session.refit()
    assert result is not None and result.calibration is not None and result.n_used <= 1000
    truth = board.truth.calibration
    np.testing.assert_allclose(result.calibration.offset, truth.offset, atol=0.3)
    snapshot = session.snapshot()
    assert snapshot.verdict.good, snapshot.verdict
    assert session.refit() is None  # nothing new since
    session.reset()
    assert session.n_samples == 0 and session.snapshot().fit is None


def test_verdict_names_what_is_missing() -> None:
    session = Session(thresholds=Thresholds(min_coverage=0.9, max_heading_sigma_deg=0.1))
    verdict = session.verdict(FitResult(None, "flat", 100, 100, 0.0, 0.0), None)
    assert not verdict.good
    assert [check[0] for check in verdict.checks if not check[3]] == ["fit", "coverage", "heading 1-sigma", "warnings"]
    assert ">= 90 %" in verdict.checks[1][2] and "<= 0.1 deg" in verdict.checks[2][2]
