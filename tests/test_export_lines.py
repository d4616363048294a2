"""Every export read line by line the way its consumer reads it, against that reader's buffer.

Readers with a fixed line buffer, from their source:

- RTIMULib ``RTIMUSettings::loadSettings`` (RTIMULib/RTIMUSettings.cpp): ``while (fgets(buf, 200, m_fd))``,
  skip a line starting with '#', ' ' or '\\n', else ``sscanf(buf, "%[^=]=%s", key, val) != 2`` is a "Bad line in
  settings file" and the function returns false. A line longer than 198 characters comes back in pieces.
- INAV ``cliProcess`` (src/main/fc/cli.c): ``static char cliBuffer[64]``; characters beyond the buffer are
  dropped, then everything from the first '#' is stripped. A command must fit in 63 characters (the 64th
  would be overwritten by the terminating zero).
- Betaflight ``processCharacter`` (src/main/cli/cli.c): ``cliBuffer[CLI_IN_BUFFER_SIZE]``, 256, the same
  rules.
- ArduPilot and PX4 parameters travel as MAVLink ``PARAM_SET``, whose ``param_id`` is ``char[16]``
  (AP_MAX_NAME_SIZE 16 in AP_Param.h): every name written must fit.

Readers without a line limit (C and C++ compilers, MATLAB/Octave, YAML and JSON parsers, Mission Planner and
QGroundControl) are only checked for the buffers above where they apply.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

import magfit
from magfit.export import FORMATS, export
from magfit.rotations import euler_matrix

#: fgets(buf, 200, f) returns a line of at most 198 characters whole, with its newline.
READER_LINE_MAX = 198
SOFT = np.array([[1.05, 0.02, -0.01], [0.02, 0.97, 0.015], [-0.01, 0.015, 0.99]])
LONG_METHOD = "ellipsoid-with-a-very-long-name-" * 12  # a user's own label: 384 characters


def _calibrations(unit: str) -> list[magfit.Calibration]:
    offset = np.array([12.0, -30.0, 7.0]) if unit == "uT" else np.array([120.0, -300.0, 70.0])
    field = 48.0 if unit == "uT" else 1024.0
    tilt = euler_matrix(3.0, -2.0, 97.0)  # no fixed rotation within 0.5 deg: custom angles
    upper = np.linalg.cholesky(SOFT @ SOFT).T  # a Cholesky root: upper triangular, same M^T M as SOFT
    return [
        magfit.Calibration("ellipsoid", offset, SOFT, field, unit=unit),
        magfit.Calibration("ellipsoid", offset, upper, field, unit=unit, details={"root": "cholesky"}),
        magfit.Calibration("vector", offset, tilt @ SOFT, field, unit=unit, frame="vehicle"),
        magfit.Calibration("vector", offset, tilt @ SOFT @ np.diag([1.0, 1.0, -1.0]), field, unit=unit,
                           frame="vehicle"),
        magfit.Calibration(LONG_METHOD, offset, SOFT, field, unit=unit, n_samples=123456),
    ]  # fmt: skip


def _texts(name: str) -> list[str]:
    unit = "counts" if FORMATS[name].unit == "counts" else "uT"
    texts = []
    for cal in _calibrations(unit):
        try:
            texts.append(export(cal, name))
        except magfit.ExportError:
            continue  # refused (a mirror, a vehicle frame the target cannot hold): nothing to read
    assert texts, name
    return texts


def fgets_pieces(text: str, size: int = 200) -> list[str]:
    """What successive ``fgets(buf, size, f)`` calls return: at most size - 1 characters, up to a newline."""
    pieces = []
    for line in text.splitlines(keepends=True):
        while line:
            pieces.append(line[: size - 1])
            line = line[size - 1 :]
    return pieces


def rtimulib_loads(text: str) -> bool:
    """RTIMUSettings::loadSettings's loop: False at the first piece sscanf("%[^=]=%s") cannot split."""
    for buf in fgets_pieces(text):
        if buf[0] in "# \n":
            continue
        if not re.match(r"[^=]+=\S+", buf):  # %[^=] needs one character, %s one non-space
            return False
    return True


def test_the_vehicle_frame_note_once_broke_rtimulib() -> None:
    # The reproducer: the NOTE of a vehicle-frame calibration was one comment line of about 261 characters.
    note = "# NOTE: frame 'vehicle': the matrix also aligns the magnetometer with the vehicle " + "x" * 180
    assert not rtimulib_loads(note + "\nCompassCalValid=true\n")


@pytest.mark.parametrize("name", ["rtimulib"])
def test_rtimulib_loads_every_file(name: str) -> None:
    for text in _texts(name):
        assert rtimulib_loads(text)
        assert max(len(line) for line in text.splitlines()) <= READER_LINE_MAX


def _cli_commands(text: str, buffer: int) -> list[str]:
    """The commands a flight controller's CLI runs: each line cut to the buffer, stripped from its first '#'."""
    commands = []
    for line in text.splitlines():
        kept = line.lstrip(" ")[:buffer]
        kept = kept.split("#", 1)[0].rstrip(" ")
        if kept:
            commands.append(kept)
    return commands


@pytest.mark.parametrize(("name", "buffer"), [("inav", 64), ("betaflight", 256)])
def test_cli_commands_fit_the_cli_buffer(name: str, buffer: int) -> None:
    for text in _texts(name):
        whole = [line.split("#", 1)[0].rstrip() for line in text.splitlines() if line.split("#", 1)[0].strip()]
        assert _cli_commands(text, buffer - 1) == whole  # nothing cut: each command fits with its terminator
        assert all(line.startswith("#") for line in text.splitlines() if "#" in line)  # comments whole lines


@pytest.mark.parametrize("name", ["ardupilot", "px4"])
def test_parameter_names_fit_mavlink_param_id(name: str) -> None:
    for text in _texts(name):
        for line in text.splitlines():
            if line.startswith("#") or not line.strip():
                continue
            parameter = line.split(",")[0] if name == "ardupilot" else line.split("\t")[2]
            assert len(parameter) <= 16, parameter


def test_every_format_is_read_here_or_has_no_line_buffer() -> None:
    buffered = {"rtimulib", "inav", "betaflight", "ardupilot", "px4"}
    unlimited = {"json", "c", "fusion", "magcal", "adafruit", "adafruit-json", "ros-madgwick", "yaml"}
    assert buffered | unlimited == set(FORMATS)
