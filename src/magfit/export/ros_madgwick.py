"""ROS ``imu_filter_madgwick``: ``mag_bias_x/y/z`` in tesla, as a ROS 2 parameter file.

``ImuFilterRos::imuMagCallback`` (imu_filter_madgwick/src/imu_filter_ros.cpp, CCNYRoboticsLab/imu_tools,
branches humble c8a27cd and noetic 4b8d5db) subtracts the bias from each ``sensor_msgs/MagneticField``
message, whose field is in tesla::

    mag_compensated = magnetic_field - (mag_bias_x, mag_bias_y, mag_bias_z)

and nothing else: the filter holds no soft-iron correction. So ``mag_bias = k * offset`` with ``k``
the factor from the samples' unit to tesla (1e-6 for µT). The parameters are declared with those
names and a range of -10 to 10 (ROS 2: ``add_parameter("mag_bias_x", ...)``; ROS 1: the dynamic
reconfigure file cfg/ImuFilterMadgwick.cfg). The file is a ROS 2 parameter file for any node name
(``/**``: the node is ``imu_filter_madgwick`` when run alone, ``imu_filter`` from the package's
launch file); for ROS 1, load the three keys into the node's namespace (``rosparam load``). The values
always carry a decimal point (``2.5e-05``, ``3.0e-05``): ``rosparam`` reads YAML 1.1, where ``3e-05`` is a
string (:func:`._common.yaml_float`).

What dropping magfit's matrix costs is said in the file as a heading error computed for the
calibration at hand (:func:`._heading.heading_error_deg`); the ``yaml`` export keeps the full matrix.
Refused: no physical unit (MagneticField is in tesla), and a vehicle-frame calibration: the filter has
no rotation parameter, and dropping the alignment would turn every heading by it (ROS states the
magnetometer's mounting in the TF tree of the message's ``frame_id`` instead); the ``yaml`` export
keeps the whole matrix.
"""

from __future__ import annotations

import numpy as np

from ..calibration import Calibration
from ..errors import ExportError
from ._common import describe, factor, float32_text, physical_unit, plain, yaml_float
from ._heading import ASSUMPTION, heading_error_deg

#: ROS 2 parameter files: "/**" matches every node name.
NODE = "/**"
AXES = "xyz"


def write_ros_madgwick(calibration: Calibration, unit: str | None = None) -> str:
    """A ROS 2 parameter file setting imu_filter_madgwick's ``mag_bias_*`` (see the module docstring).

    Raises
    ------
    ExportError
        No physical unit.
    OptionError
        ``unit`` is not a unit magfit knows.
    """
    if calibration.frame == "vehicle":
        raise ExportError(
            "imu_filter_madgwick holds a bias only and no rotation, so it cannot carry this vehicle-frame "
            "calibration's alignment; export to 'yaml' (the whole matrix) and state the mounting in the TF of "
            "the messages' frame_id"
        )
    source = physical_unit(calibration, unit, "ros-madgwick", "tesla")
    k = factor(source, "T")
    bias = k * calibration.offset
    loss = heading_error_deg(calibration, np.eye(3), calibration.offset)
    lines = [
        "# imu_filter_madgwick magnetometer bias (ROS 2 parameter file). Generated file: re-export instead of editing.",
        *(f"# {plain(line)}" for line in describe(calibration, source.name)),
        "# imu_filter_madgwick corrects each sensor_msgs/MagneticField (tesla) in imuMagCallback:",
        "#   mag_compensated = magnetic_field - (mag_bias_x, mag_bias_y, mag_bias_z)",
        f"# mapping: mag_bias = offset * {float32_text(k)} ({source.name} -> T).",
        "# Lost: the filter holds the hard-iron offset only. Dropping magfit's matrix (soft iron) costs",
        f"#   a heading error of up to {loss:.2f} deg ({ASSUMPTION}); the 'yaml' export keeps it.",
        "# Use: ros2 run imu_filter_madgwick imu_filter_madgwick_node --ros-args --params-file <this file>",
        "# ROS 1: rosparam load the three mag_bias_* keys into the node's namespace.",
        f'"{NODE}":',
        "  ros__parameters:",
        *(f"    mag_bias_{a}: {yaml_float(v)}" for a, v in zip(AXES, bias, strict=True)),
    ]
    return "\n".join(lines) + "\n"
