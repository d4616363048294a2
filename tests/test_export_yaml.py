"""YAML floats every reader takes as floats: PyYAML (YAML 1.1, ROS 1's rosparam) and the YAML 1.2 core schema.

The reproducer: an offset of 3e-05 T written as ``3e-05`` (Python's repr) has no decimal point, and YAML 1.1's
float pattern requires one, so PyYAML returned the string "3e-05".
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

import magfit
from magfit.export import export
from magfit.export._common import yaml_float

#: YAML 1.2.2 core schema, 10.3.2 (tag resolution), the float patterns.
YAML12_FLOAT = re.compile(r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?")
VALUES = [3e-05, -3e-05, 1e20, 1e-300, 5e-324, 1.7976931348623157e308, 0.0, -0.0, 1.0, 1e16, 123456789.0, 0.1,
          2.5e-05, 52.9, -40.0]  # fmt: skip


def test_repr_was_read_as_a_string_by_pyyaml() -> None:
    assert yaml.safe_load("x: " + repr(3e-05))["x"] == "3e-05"  # the bug this guards against


@pytest.mark.parametrize("value", VALUES)
def test_every_reader_reads_the_same_double(value: float) -> None:
    text = yaml_float(value)
    loaded = yaml.safe_load(f"x: {text}")["x"]
    assert isinstance(loaded, float) and loaded == value and np.signbit(loaded) == np.signbit(value)
    assert YAML12_FLOAT.fullmatch(text) and float(text) == value


def test_random_doubles_round_trip() -> None:
    rng = np.random.default_rng(7)
    values = rng.standard_normal(2000) * 10.0 ** rng.integers(-30, 30, 2000)
    for value in values:
        loaded = yaml.safe_load(f"x: {yaml_float(float(value))}")["x"]
        assert isinstance(loaded, float) and loaded == value


@pytest.mark.parametrize("name", ["yaml", "ros-madgwick"])
def test_small_values_in_the_files_are_floats(name: str) -> None:
    # An offset of 3e-05 uT, and in ros-madgwick's tesla a bias of 3e-05 T (30 uT): both once strings.
    cal = magfit.Calibration("ellipsoid", np.array([3e-05, 30.0, -1e-07]), np.eye(3), 48.0, unit="uT")
    data = yaml.safe_load(export(cal, name))
    if name == "yaml":
        values = data["magnetometer_calibration"]["offset"]
        assert values == [3e-05, 30.0, -1e-07]
    else:
        params = data["/**"]["ros__parameters"]
        values = [params[f"mag_bias_{a}"] for a in "xyz"]
        np.testing.assert_allclose(values, [3e-11, 3e-05, -1e-13], rtol=1e-12)
    assert all(isinstance(v, float) for v in values)
