"""Write the synthetic converter fixtures of this folder, with their truth in truth.json.

Each file has the header its converter writes (checked against the converter's source, named below) and
magnetometer samples of a known calibration: ``raw = distortion @ field_direction * strength + offset`` plus
noise, the direction turned through a full tumble. Run from the repository root:
``.venv/bin/python tests/data/converters/make_fixtures.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent


def tumble(n: int, rng: np.random.Generator) -> np.ndarray:
    """Unit field directions along a smooth path over the whole sphere (a sensor turned by hand)."""
    t = np.linspace(0.0, 1.0, n)
    azimuth = 2 * np.pi * 7.3 * t + 0.3 * rng.standard_normal()
    polar = np.arccos(np.clip(1 - 2 * ((3.1 * t) % 1.0), -1, 1))
    return np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])


def compass(n: int, strength: float, offset: list[float], distortion: list[list[float]], noise: float, seed: int):
    rng = np.random.default_rng(seed)
    directions = tumble(n, rng)
    raw = strength * directions @ np.asarray(distortion).T + np.asarray(offset)
    return raw + rng.normal(scale=noise, size=raw.shape), {
        "field_strength": strength,
        "offset": offset,
        "distortion": distortion,
        "noise": noise,
    }


def blackbox(truth: dict) -> None:
    # blackbox-tools src/blackbox_decode.c, outputFieldNamesHeader: names joined by ", ", a " (unit)" after
    # the fields it converts (time, vbat, amperage, BaroAlt); raw fields such as magADC are printed "%3d".
    names = (
        ["loopIteration", "time (us)"]
        + [f"axis{term}[{i}]" for term in "PIDF" for i in range(3)]
        + [f"rcCommand[{i}]" for i in range(4)]
        + [f"setpoint[{i}]" for i in range(4)]
        + ["vbatLatest (V)", "amperageLatest (A)", "BaroAlt (cm)"]
        + [f"magADC[{i}]" for i in range(3)]
        + [f"gyroADC[{i}]" for i in range(3)]
        + [f"accSmooth[{i}]" for i in range(3)]
        + [f"debug[{i}]" for i in range(4)]
        + [f"motor[{i}]" for i in range(4)]
        + ["flightModeFlags (flags)", "stateFlags (flags)", "failsafePhase (flags)"]
    )
    samples, truth["blackbox_magadc.csv"] = compass(
        400, 480.0, [957.0, 417.0, 502.0], [[1.0, 0.04, 0.0], [0.04, 0.93, 0.02], [0.0, 0.02, 1.08]], 2.0, 1
    )
    rng = np.random.default_rng(11)
    lines = [", ".join(names)]
    for k, mag in enumerate(np.rint(samples).astype(int)):
        row = [str(32 * k), str(1_000_000 + 4000 * k)]
        row += [f"{v:3d}" for v in rng.integers(-40, 40, 12)]
        row += [f"{v:3d}" for v in rng.integers(-500, 500, 3)] + ["1250"]
        row += [f"{v:3d}" for v in rng.integers(-200, 200, 3)] + ["0"]
        row += ["16.4", "3.21", f"{int(rng.integers(100, 140))}"]
        row += [f"{v:3d}" for v in mag]
        row += [f"{v:3d}" for v in rng.integers(-900, 900, 3)]
        row += [f"{v:3d}" for v in rng.integers(-300, 300, 3) + np.array([0, 0, 2048])]
        row += [f"{v:3d}" for v in rng.integers(-100, 100, 4)]
        row += [f"{v:3d}" for v in rng.integers(1000, 1200, 4)]
        row += ["ANGLE_MODE", "SMALL_ANGLE|ACC_CALIBRATED", "IDLE"]
        lines.append(", ".join(row))
    (HERE / "blackbox_magadc.csv").write_text("\n".join(lines) + "\n")


def mavlogdump(truth: dict) -> None:
    # pymavlink tools/mavlogdump.py, --format csv on a .bin with --types MAG: "timestamp" and the FMT
    # message's columns; recent ArduPilot logs every compass as MAG with its instance I (0-based).
    names = ["timestamp", "TimeUS", "I", "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ", "MOX", "MOY", "MOZ",
             "Health", "S"]  # fmt: skip
    first, truth["mavlogdump_mag.csv I=0"] = compass(
        500, 520.0, [35.0, -60.0, 110.0], [[1.05, 0.0, 0.03], [0.0, 0.97, 0.0], [0.03, 0.0, 0.98]], 1.5, 2
    )
    second, truth["mavlogdump_mag.csv I=1"] = compass(
        500, 505.0, [-140.0, 80.0, -25.0], [[0.94, 0.05, 0.0], [0.05, 1.02, -0.04], [0.0, -0.04, 1.04]], 1.5, 3
    )
    lines = [",".join(names)]
    for k in range(500):
        for instance, samples, ofs in ((0, first, (12, -7, 30)), (1, second, (-40, 22, 5))):
            time_us = 60_000_000 + 100_000 * k + 1_300 * instance
            mag = np.rint(samples[k]).astype(int)
            row = [f"{1_700_000_000 + time_us / 1e6:.8f}", str(time_us), str(instance)]
            row += [str(v) for v in mag] + [str(v) for v in ofs] + ["0", "0", "0", "1", "1"]
            lines.append(",".join(row))
    (HERE / "mavlogdump_mag.csv").write_text("\n".join(lines) + "\n")


def ros(truth: dict) -> None:
    # rostopic echo -p / rosbag's CSV export of sensor_msgs/MagneticField: "%time" and "field."-prefixed fields;
    # the field in tesla (the message definition), a 3x3 covariance flattened to 9 columns.
    names = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id"]
    names += [f"field.magnetic_field.{axis}" for axis in "xyz"]
    names += [f"field.magnetic_field_covariance{i}" for i in range(9)]
    samples, truth["ros_magnetic_field.csv"] = compass(
        400, 4.9e-5, [1.2e-5, -0.6e-5, 2.1e-5], [[1.1, 0.0, 0.0], [0.0, 0.95, 0.05], [0.0, 0.05, 0.96]], 2e-7, 4
    )
    lines = [",".join(names)]
    for k, field in enumerate(samples):
        stamp = 1_700_000_000_000_000_000 + 20_000_000 * k
        row = [str(stamp + 150_000), str(k), str(stamp), "imu_link"] + [f"{v:.9e}" for v in field] + ["0.0"] * 9
        lines.append(",".join(row))
    (HERE / "ros_magnetic_field.csv").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    truth: dict = {}
    blackbox(truth)
    mavlogdump(truth)
    ros(truth)
    (HERE / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
