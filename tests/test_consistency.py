"""A vehicle's compasses against each other: the relative rotation (Wahba), the compass mounted at another angle
than it declares named with its angle, the one that follows the current, the firmwares' pre-arm figures —
each against a simulated truth, through the library and through a DataFlash log and ``magfit calibrate``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import magfit
from magfit.cli import cli
from magfit.consistency import (
    CompassField,
    compare_compasses,
    compare_fields,
    wahba_rotation,
)
from magfit.errors import SampleError
from magfit.rotations import angle_between_deg, euler_angles, euler_matrix, polar_decomposition
from magfit.vehicle import simulate_vehicle
from test_sources_dataflash import DataFlashWriter

FIELD = 480.0
SOFT = [
    np.array([[1.10, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.0]]),
    np.array([[0.97, 0.0, 0.04], [0.0, 1.08, 0.0], [0.04, 0.0, 1.0]]),
    np.array([[1.02, 0.01, 0.0], [0.01, 1.0, 0.0], [0.0, 0.0, 0.98]]),
]
HARD = [np.array([120.0, -60.0, 200.0]), np.array([-40.0, 85.0, -150.0]), np.array([10.0, 30.0, -20.0])]


def _vehicle(motion: str = "tumble", n: int = 2400, seed: int = 1):
    sim = simulate_vehicle(
        n, motion, rate_hz=20.0, field_strength=FIELD, inclination_deg=60.0, max_tilt_deg=30.0, seed=seed
    )
    return sim.time_s, np.einsum("nji,j->ni", sim.attitude, sim.field_world), sim.attitude


def _fields(mountings, *, motion="tumble", attitude=True, current=None, seed=1):
    """Calibrated fields of compasses whose true mountings are ``mountings`` (all declaring identity)."""
    rng = np.random.default_rng(seed)
    time_s, body, att = _vehicle(motion, seed=seed)
    _, dance, _ = _vehicle("tumble", seed=seed + 100)
    out = []
    for k, mounting in enumerate(mountings):
        calibration = magfit.fit((dance @ mounting) @ SOFT[k].T + HARD[k], method="ellipsoid")
        raw = (body @ mounting) @ SOFT[k].T + HARD[k] + rng.normal(0, 1.5, body.shape)
        if current is not None and k == current[0]:
            raw = raw + np.outer(current[1], current[2])  # the sensor sees k·I on top of the field
        _, symmetric = polar_decomposition(calibration.matrix)
        field = (raw - calibration.offset) @ symmetric.T
        out.append(
            CompassField(
                f"MAG/{k}", time_s, field, "mG", np.eye(3), att[:, 2, :] if attitude else None, k, 1000 + k, "ardupilot"
            )
        )
    return out


def test_wahba_recovers_a_known_rotation_and_refuses_bad_shapes() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 3))
    truth = euler_matrix(10.0, -35.0, 120.0)
    b = a @ truth.T + rng.normal(0, 1e-3, a.shape)
    assert angle_between_deg(wahba_rotation(a, b), truth) < 0.05
    assert np.allclose(wahba_rotation(a, a), np.eye(3), atol=1e-12)
    with pytest.raises(SampleError, match=r"\(N, 3\)"):
        wahba_rotation(a, b.T)


@pytest.mark.parametrize(
    ("angles", "nearest_id"), [((0.0, 0.0, 45.0), 1), ((0.0, 0.0, 90.0), 2), ((180.0, 0.0, 0.0), 8)]
)
def test_a_rotated_second_compass_is_named_with_its_angle_and_the_firmware_rotation(angles, nearest_id) -> None:
    truth = euler_matrix(*angles)
    comparison = compare_fields(_fields([np.eye(3), truth]))
    m = comparison.misoriented
    assert m is not None and m.sensor == "MAG/1"
    assert abs(m.angle_deg - angle_between_deg(np.eye(3), truth)) < 1.0
    assert angle_between_deg(m.orientation, truth) < 1.0  # the orientation it should declare is the truth
    assert m.nearest is not None and m.nearest.id == nearest_id and m.nearest.angle_deg < 1.0
    (finding,) = [r for r in comparison.findings if r.code == "compass_misoriented"]
    assert finding.remedy == (("COMPASS_ORIENT2", str(nearest_id)),)
    assert comparison.priority[0] == "MAG/0"


def test_a_rotated_first_compass_is_named_too_and_the_angle_carries_a_small_stated_uncertainty() -> None:
    comparison = compare_fields(_fields([euler_matrix(0.0, 0.0, 45.0), np.eye(3)], motion="flight"))
    m = comparison.misoriented
    assert m is not None and m.sensor == "MAG/0" and abs(m.angle_deg - 45.0) < 1.0
    assert 0 < m.sigma_deg < 1.0
    assert comparison.priority == ("MAG/1", "MAG/0")


def test_a_tilt_no_table_entry_matches_is_named_without_an_orient_remedy() -> None:
    comparison = compare_fields(_fields([np.eye(3), euler_matrix(20.0, 0.0, 0.0)]))
    m = comparison.misoriented
    assert m is not None and m.sensor == "MAG/1" and abs(m.angle_deg - 20.0) < 1.0
    assert m.nearest is not None and m.nearest.angle_deg > 15.0
    (finding,) = [r for r in comparison.findings if r.code == "compass_misoriented"]
    assert finding.remedy == ()


def test_correctly_mounted_compasses_raise_nothing() -> None:
    comparison = compare_fields(_fields([np.eye(3), np.eye(3)], motion="flight"))
    assert comparison.misoriented is None and comparison.codes == ()
    assert comparison.pairs[0].angle_deg < 1.0 and comparison.pairs[0].determined
    assert comparison.ardupilot[0].fail_share == 0.0 and comparison.px4[0].fail_share == 0.0


def test_two_compasses_without_attitude_say_that_which_is_wrong_is_unknown() -> None:
    comparison = compare_fields(_fields([np.eye(3), euler_matrix(0.0, 0.0, 45.0)], attitude=False))
    assert comparison.misoriented is None
    assert "compass_misoriented" in comparison.codes
    assert abs(comparison.pairs[0].angle_deg - 45.0) < 1.0


def test_three_compasses_name_the_odd_one_by_majority() -> None:
    comparison = compare_fields(_fields([np.eye(3), np.eye(3), euler_matrix(0.0, 0.0, -90.0)], attitude=False))
    m = comparison.misoriented
    assert m is not None and m.sensor == "MAG/2" and abs(m.angle_deg - 90.0) < 1.0
    assert m.nearest is not None and m.nearest.id == 6  # ROTATION_YAW_270
    assert len(comparison.px4) == 2  # PX4 compares the first two others with the primary


@pytest.mark.parametrize("follower", [0, 1])
def test_the_compass_that_follows_the_current_is_named_with_its_share_of_the_field(follower: int) -> None:
    time_s, _, _ = _vehicle()
    rng = np.random.default_rng(5)
    amps = 5.0 + 35.0 * np.abs(np.sin(time_s / 7.0)) + rng.normal(0, 0.5, len(time_s))
    per_amp = np.array([1.5, -1.0, 3.0])  # mG per ampere
    fields = _fields([np.eye(3), np.eye(3)], current=(follower, amps, per_amp))
    comparison = compare_fields(fields, regressor=(time_s, amps, "current", "BAT.Curr"))
    effect = comparison.pairs[0].current
    assert effect is not None and effect.follower == (f"MAG/{follower}",)
    expected = 100 * np.linalg.norm(per_amp) * amps.max() / FIELD
    assert abs(effect.at_full_pct - expected) < 0.25 * expected
    assert "compass_follows_current" in comparison.codes
    assert comparison.priority[0] == f"MAG/{1 - follower}"
    quiet = compare_fields(_fields([np.eye(3), np.eye(3)]), regressor=(time_s, amps, "current", "BAT.Curr"))
    assert "compass_follows_current" not in quiet.codes


def test_the_firmware_figures_are_their_one_line_formulas() -> None:
    time_s = np.arange(100) * 0.1
    primary = np.tile([200.0, 0.0, 400.0], (100, 1))
    turned = np.tile([200.0 * math.cos(math.radians(70)), 200.0 * math.sin(math.radians(70)), 400.0], (100, 1))
    fields = [CompassField("A", time_s, primary, "mG"), CompassField("B", time_s, turned, "mG")]
    comparison = compare_fields(fields)
    ap = comparison.ardupilot[0]
    cosine = np.dot(primary[0], turned[0]) / np.linalg.norm(primary[0]) / np.linalg.norm(turned[0])
    assert ap.xyz_angle_deg == pytest.approx(math.degrees(math.acos(cosine)), abs=1e-6)
    assert ap.xy_angle_deg == pytest.approx(70.0, abs=1e-6)
    assert ap.xy_length == pytest.approx(2 * 200.0 * math.sin(math.radians(35)), abs=1e-6)
    assert ap.fail_share == 1.0 and any("horizontal angle" in f for f in ap.failing)
    px = comparison.px4[0]
    assert px.angle_deg == pytest.approx(ap.xyz_angle_deg)
    assert px.filtered_max_deg == pytest.approx(ap.xyz_angle_deg * (1 - 0.95**100), rel=1e-9)
    assert "compasses_inconsistent" in comparison.codes
    gauss = [CompassField("A", time_s, primary / 1000, "G"), CompassField("B", time_s, turned / 1000, "G")]
    assert compare_fields(gauss).ardupilot[0].xy_length == pytest.approx(ap.xy_length)


def test_bad_inputs_are_one_line_errors() -> None:
    time_s = np.arange(100) * 0.1
    one = CompassField("A", time_s, np.ones((100, 3)), "mG")
    with pytest.raises(SampleError, match="at least two"):
        compare_fields([one])
    with pytest.raises(SampleError, match="different units"):
        compare_fields([one, CompassField("B", time_s, np.ones((100, 3)), "G")])
    with pytest.raises(SampleError, match="share only 0 time stamps"):
        compare_fields([one, CompassField("B", time_s + 100.0, np.ones((100, 3)), "mG")])


# ---------------------------------------------------------------------------------------------- a DataFlash log


def write_two_compass_log(
    path: Path, mounting2: np.ndarray, *, amps_per_mg: float = 0.0, parameters: dict[str, float] | None = None
) -> None:
    """A tumble logged by ArduPilot with two compasses (both declared ROTATION_NONE, identity calibration), the
    second mounted at ``mounting2``; ATT, and BAT with a current the first compass sees ``amps_per_mg`` of."""
    time_s, body, attitude = _vehicle("tumble", n=2400, seed=3)
    rng = np.random.default_rng(3)
    amps = 5.0 + 35.0 * np.abs(np.sin(time_s / 7.0))
    raws = [
        body @ SOFT[0].T + HARD[0] + np.outer(amps, [amps_per_mg, 0.0, 2 * amps_per_mg]),
        (body @ mounting2) @ SOFT[1].T + HARD[1],
    ]
    writer = DataFlashWriter()
    writer.define(129, "PARM", "QNf", "TimeUS,Name,Value")
    writer.define(130, "MAG", "QBfff", "TimeUS,I,MagX,MagY,MagZ")
    writer.define(131, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw")
    writer.define(132, "BAT", "QBf", "TimeUS,Inst,Curr")
    for k, s in enumerate(("", "2")):
        for axis in "XYZ":
            for name, value in (("OFS", 0.0), ("DIA", 1.0), ("ODI", 0.0)):
                writer.write("PARM", 500_000, f"COMPASS_{name}{s}_{axis}", value)
        writer.write("PARM", 500_000, f"COMPASS_SCALE{s}", 0.0)
        writer.write("PARM", 500_000, f"COMPASS_DEV_ID{s}", float(97539 + k))
        writer.write("PARM", 500_000, f"COMPASS_ORIENT{s}", 0.0)
        writer.write("PARM", 500_000, f"COMPASS_EXTERN{'AL' if k == 0 else s}", 1.0)
    writer.write("PARM", 500_000, "COMPASS_MOTCT", 0.0)
    writer.write("PARM", 500_000, "AHRS_ORIENTATION", 0.0)
    for name, value in (parameters or {}).items():
        writer.write("PARM", 500_000, name, value)
    for j, t in enumerate(time_s):
        stamp = 1_000_000 + round(t * 1e6)
        roll, pitch, yaw = euler_angles(attitude[j])
        writer.write("ATT", stamp, roll, pitch, yaw % 360.0)
        writer.write("BAT", stamp, 0, float(amps[j]))
        for k in range(2):
            writer.write("MAG", stamp, k, *(float(v) for v in raws[k][j] + rng.normal(0, 1.0, 3)))
    path.write_bytes(writer.bytes())


def test_a_log_whose_second_compass_is_rotated_45_degrees_names_it(tmp_path: Path) -> None:
    log = tmp_path / "rotated.bin"
    write_two_compass_log(log, euler_matrix(0.0, 0.0, 45.0))
    result = magfit.calibrate_file(log)
    comparison = compare_compasses(result)
    m = comparison.misoriented
    assert m is not None and m.sensor == "MAG/1" and abs(m.angle_deg - 45.0) < 2.0
    assert m.nearest is not None and m.nearest.name == "ROTATION_YAW_45"
    assert comparison.firmware == "ardupilot" and comparison.device_ids == (97539, 97540)
    assert any("BAT.Curr" in note for note in comparison.notes)
    assert comparison.pairs[0].current is not None and comparison.pairs[0].current.follower == ()


@pytest.mark.slow
def test_calibrate_prints_the_compasses_block_and_inspect_a_quick_check(tmp_path: Path) -> None:
    log = tmp_path / "rotated.bin"
    write_two_compass_log(log, euler_matrix(0.0, 0.0, 45.0))
    run = CliRunner().invoke(cli, ["calibrate", str(log)])
    assert run.exit_code == 0, run.output
    assert "compasses" in run.output and "COMPASS_ORIENT2 1" in run.output
    assert "ArduPilot check" in run.output
    run = CliRunner().invoke(cli, ["inspect", str(log)])
    assert run.exit_code == 0, run.output
    quick = run.output.split("compasses", 1)[-1]
    angle = float(quick.split("is turned ", 1)[1].split("°", 1)[0])
    assert "MAG/1" in quick and abs(angle - 45.0) < 1.0


def test_compasses_that_no_rotation_brings_together_are_said_to_disagree_not_misoriented() -> None:
    first = _fields([np.eye(3)], seed=1)[0]
    second = _fields([np.eye(3)], seed=2)[0]  # another flight: not the same field at the same instants
    comparison = compare_fields(
        [first, CompassField("MAG/1", first.time_s, second.field, "mG", np.eye(3), second.down)]
    )
    assert comparison.misoriented is None
    assert "compasses_inconsistent" in comparison.codes
    assert any("under any rotation" in reason for reason in comparison.findings)


def test_the_report_fragment_shows_the_rotation_the_findings_and_the_firmware_tests(tmp_path: Path) -> None:
    from magfit.firmware_checks import explain_log
    from magfit.report import compasses_html

    log = tmp_path / "rotated.bin"
    write_two_compass_log(log, euler_matrix(0.0, 0.0, 45.0))
    result = magfit.calibrate_file(log)
    fragment = compasses_html(compare_compasses(result), explain_log(result))
    assert fragment.startswith("<div class='compasses'>") and fragment.endswith("</div>")
    assert "compass_misoriented" in fragment and "MAG/1" in fragment
    assert "Compass::consistent" in fragment and "orientation" in fragment
    angle = float(fragment.split("<td>MAG/1</td><td>", 1)[1].split(" ", 1)[0])
    assert abs(angle - 45.0) < 2.0
    assert "<script" not in fragment  # every text escaped


@pytest.mark.slow
def test_a_report_section_carries_the_fragment(tmp_path: Path) -> None:
    pytest.importorskip("plotly")
    from magfit.report import ReportSection, compasses_html, report_html

    fields = _fields([np.eye(3), euler_matrix(0.0, 0.0, 45.0)])
    fragment = compasses_html(compare_fields(fields))
    sim = magfit.simulate(500, seed=1)
    section = ReportSection("log", sim.samples, (magfit.fit(sim.samples),), extra_html=(fragment,))
    assert fragment in report_html([section])


def test_the_regressor_is_read_in_amperes_from_new_and_old_logs(tmp_path: Path) -> None:
    from magfit.consistency import _power_regressor

    for name, letters, scale in (("BAT", "QBf", 1.0), ("CURR", "QBh", 100.0)):
        writer = DataFlashWriter()
        writer.define(129, name, letters, "TimeUS,Inst,Curr")
        for j in range(30):
            amps = 5.0 + j
            writer.write(name, 1_000_000 + 100_000 * j, 0, amps * scale if letters[-1] == "f" else int(amps * scale))
            writer.write(name, 1_000_000 + 100_000 * j, 1, 99.0 if letters[-1] == "f" else 9900)  # another battery
        log = tmp_path / f"{name}.bin"
        log.write_bytes(writer.bytes())
        regressor = _power_regressor(log)
        assert regressor is not None and regressor[2:] == ("current", f"{name}.Curr")
        np.testing.assert_allclose(regressor[1], 5.0 + np.arange(30))
        np.testing.assert_allclose(regressor[0], 1.0 + 0.1 * np.arange(30))


@pytest.mark.slow
def test_a_px4_log_names_the_compass_whose_cal_mag_rot_is_wrong(tmp_path: Path) -> None:
    from scipy.spatial.transform import Rotation

    from magfit.rotations import standard_rotations
    from test_sources_ulog import ULogWriter

    time_s, body, attitude = _vehicle("tumble", n=2400, seed=4)
    table = standard_rotations("px4")
    declared = {0: 6, 1: 0}  # CAL_MAG0_ROT 6 (yaw 270, right), CAL_MAG1_ROT 0 (but mounted yaw 45: PX4's 1)
    truly = {0: table[6].matrix, 1: table[1].matrix}
    devices = {0: 592905, 1: 600001}
    writer = ULogWriter()
    writer.format("sensor_mag", [("uint64_t", "timestamp"), ("uint32_t", "device_id"), *(("float", a) for a in "xyz")])
    writer.format("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")])
    for k in (0, 1):
        writer.parameter(f"CAL_MAG{k}_ID", devices[k])
        writer.parameter(f"CAL_MAG{k}_ROT", declared[k])
    for k in (0, 1):
        writer.subscribe("sensor_mag", k)
    writer.subscribe("vehicle_attitude", 0)
    raw = {k: ((body @ truly[k]) @ SOFT[k].T + HARD[k]) / 1000.0 for k in (0, 1)}  # gauss; sensor = Mᵀ body
    q = Rotation.from_matrix(attitude).as_quat()
    for j, t in enumerate(time_s):
        stamp = 1_000_000 + round(t * 1e6)
        writer.data("vehicle_attitude", 0, stamp - 1000, q[j, 3], q[j, 0], q[j, 1], q[j, 2])
        for k in (0, 1):
            writer.data("sensor_mag", k, stamp, devices[k], *raw[k][j])
    log = tmp_path / "px4.ulg"
    log.write_bytes(writer.bytes())
    comparison = compare_compasses(magfit.calibrate_file(log, "ellipsoid"))
    m = comparison.misoriented
    assert comparison.firmware == "px4"
    assert m is not None and m.sensor == "sensor_mag/1" and abs(m.angle_deg - 45.0) < 2.0
    assert m.nearest is not None and m.nearest.id == 1
    (finding,) = [r for r in comparison.findings if r.code == "compass_misoriented"]
    assert finding.remedy == (("CAL_MAG1_ROT", "1"),)


def test_three_compasses_all_apart_name_none_but_say_so() -> None:
    mountings = [np.eye(3), euler_matrix(0.0, 0.0, 45.0), euler_matrix(0.0, 0.0, -60.0)]
    comparison = compare_fields(_fields(mountings, attitude=False))
    assert comparison.misoriented is None and "compass_misoriented" in comparison.codes


@pytest.mark.slow
def test_a_compass_not_used_for_yaw_is_not_checked_by_ardupilots_prearm(tmp_path: Path) -> None:
    log = tmp_path / "unused.bin"
    write_two_compass_log(log, euler_matrix(0.0, 0.0, 90.0), parameters={"COMPASS_USE2": 0.0})
    comparison = compare_compasses(magfit.calibrate_file(log))
    (figures,) = comparison.ardupilot
    assert not figures.checked and figures.xy_angle_deg == pytest.approx(90.0, abs=2.0)
    assert "compasses_inconsistent" not in comparison.codes  # PX4's figures are not findings on an ArduPilot log
    assert comparison.misoriented is not None and comparison.misoriented.sensor == "MAG/1"
    used = tmp_path / "used.bin"
    write_two_compass_log(used, euler_matrix(0.0, 0.0, 90.0))
    assert "compasses_inconsistent" in compare_compasses(magfit.calibrate_file(used)).codes
