"""A simulated board: a magnetometer of known calibration turned by a hand, printing MotionCal lines.

The readings follow the paper's model (eq. 1, :func:`magfit.simulate.simulate`) at attitudes from a
smooth random walk: the angular velocity is an Ornstein-Uhlenbeck process (a hand that turns at about
``speed_dps``, changing direction over ``turn_time`` seconds), so successive samples are close, as from a
real sensor, and the attitudes drift over the whole sphere within a minute or so.

The board prints what Adafruit's calibration sketches print: ``Raw:`` lines (accelerometer in 1/8192 g,
gyroscope in 1/16 °/s, magnetometer in 0.1 µT, as integers) ended by CR LF, and it receives MotionCal's
68-byte calibration packet the way those sketches do (byte by byte: signature 117, 84, then CRC-16 over
the 68 bytes must give 0), answering with its ``Cal1:`` / ``Cal2:`` lines. Tests and ``magfit live
--simulate`` use it; it knows nothing of the code that reads it.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..calibration import Calibration
from ..simulate import simulate
from .packet import PACKET_SIZE, SIGNATURE, crc16

__all__ = ["BoardTruth", "SimulatedBoard"]

#: Accelerometer counts per g and gyroscope counts per °/s of MotionCal's Raw: lines (imuread.h).
_ACCEL_COUNTS_PER_G = 8192
_GYRO_COUNTS_PER_DPS = 16


@dataclass(frozen=True)
class BoardTruth:
    """The simulated sensor's eq. (1) parameters, µT (the truth tests compare a calibration with)."""

    soft_iron: NDArray[np.float64]
    hard_iron: NDArray[np.float64]
    field_strength: float
    inclination_deg: float
    noise: float

    @property
    def calibration(self) -> Calibration:
        """The calibration that undoes the distortion: offset V, matrix W⁻¹, field B, in µT."""
        matrix = np.asarray(np.linalg.inv(self.soft_iron), dtype=np.float64)
        return Calibration("truth", self.hard_iron, matrix, self.field_strength, unit="uT")


def default_truth() -> BoardTruth:
    """A small breakout board near some iron: 48 µT field, a 40 µT offset, semi-axes within ±8 %."""
    angle = math.radians(25.0)
    turn = np.array([[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0, 0, 1.0]])
    soft_iron = turn @ np.diag([1.08, 0.95, 0.98]) @ turn.T
    return BoardTruth(soft_iron, np.array([12.5, -30.2, 21.7]), 48.0, 64.0, 0.25)


class SimulatedBoard:
    """A board turned by a hand: call :meth:`raw_lines` for the next samples' text.

    Parameters
    ----------
    truth : BoardTruth, optional
        The sensor (default :func:`default_truth`).
    rate_hz : float
        Samples per second of simulated time.
    speed_dps : float
        Typical turning speed of the hand, degrees per second.
    turn_time : float
        Seconds over which the hand's turning direction changes (the walk's correlation time).
    seed : int
        Seed of the walk and of the noise.
    """

    def __init__(
        self,
        truth: BoardTruth | None = None,
        *,
        rate_hz: float = 100.0,
        speed_dps: float = 120.0,
        turn_time: float = 1.5,
        seed: int = 0,
    ) -> None:
        from scipy.spatial.transform import Rotation  # scipy is a core dependency; imported on use

        self._rotation = Rotation
        self.truth = truth if truth is not None else default_truth()
        self.rate_hz = float(rate_hz)
        self._speed = math.radians(speed_dps)
        self._turn_time = float(turn_time)
        self._rng = np.random.default_rng(seed)
        self._attitude = Rotation.identity()
        self._omega = self._rng.normal(0.0, self._speed / math.sqrt(3.0), 3)
        self.samples_sent = 0
        # The receiving side of the sketches: bytes of a packet being collected, and what it stored.
        self._incoming = bytearray()
        self.received: list[bytes] = []
        self.stored: tuple[float, ...] | None = None
        self._echo_pending = False

    # ------------------------------------------------------------------ motion and readings

    def _walk(self, n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The next ``n`` attitudes (roll, pitch, yaw in degrees, eq. 1) and angular velocities (rad/s)."""
        dt = 1.0 / self.rate_hz
        decay = math.exp(-dt / self._turn_time)
        # Stationary spread of each component: speed / sqrt(3), so |ω| is about the speed.
        kick = self._speed / math.sqrt(3.0) * math.sqrt(1.0 - decay * decay)
        omegas = np.empty((n, 3))
        steps = []
        omega = self._omega
        for i in range(n):
            omega = decay * omega + kick * self._rng.standard_normal(3)
            omegas[i] = omega
            steps.append(omega * dt)
        self._omega = omega
        rotations = []
        attitude = self._attitude
        for step in self._rotation.from_rotvec(np.array(steps)):
            attitude = attitude * step  # turned in the body frame, as a hand turns the board
            rotations.append(attitude)
        self._attitude = attitude
        stacked = self._rotation.concatenate(rotations)
        # The rotation taking earth-frame vectors into the sensor frame is the inverse of the attitude.
        return np.degrees(stacked.inv().as_euler("XYZ")), omegas

    def readings(self, n: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The next ``n`` samples: magnetometer (µT, eq. 1 with noise), accelerometer (g), gyroscope (°/s)."""
        attitudes, omegas = self._walk(n)
        t = self.truth
        seed = int(self._rng.integers(1 << 31))
        mag = simulate(
            n,
            soft_iron=t.soft_iron,
            hard_iron=t.hard_iron,
            field_strength=t.field_strength,
            inclination_deg=t.inclination_deg,
            noise=t.noise,
            orientations=attitudes,
            seed=seed,
        ).samples
        gravity = simulate(n, field_strength=1.0, inclination_deg=90.0, orientations=attitudes).samples
        self.samples_sent += n
        return mag, gravity, np.degrees(omegas)

    def raw_lines(self, n: int) -> bytes:
        """The next ``n`` samples as MotionCal ``Raw:`` lines (CR LF), then any pending ``Cal1:``/``Cal2:`` echo."""
        if n <= 0:
            return self._echo()
        mag, accel, gyro = self.readings(n)
        counts = np.column_stack(
            [
                np.round(accel * _ACCEL_COUNTS_PER_G),
                np.round(gyro * _GYRO_COUNTS_PER_DPS),
                np.round(mag / 0.1),  # 0.1 µT per count, MotionCal's UT_PER_COUNT
            ]
        )
        counts = np.clip(counts, -32768, 32767).astype(np.int64)
        text = "".join("Raw:" + ",".join(map(str, row)) + "\r\n" for row in counts.tolist())
        return text.encode("ascii") + self._echo()

    # ------------------------------------------------------------------ receiving a calibration

    def receive(self, data: bytes) -> None:
        """Bytes from the host, parsed byte by byte as the sketches' ``receiveCalibration`` does."""
        for byte in data:
            if not self._incoming and byte != SIGNATURE[0]:
                continue
            if len(self._incoming) == 1 and byte != SIGNATURE[1]:
                self._incoming.clear()
                continue
            self._incoming.append(byte)
            if len(self._incoming) < PACKET_SIZE:
                continue
            packet = bytes(self._incoming)
            self._incoming.clear()
            if crc16(packet) == 0:
                self.received.append(packet)
                self.stored = struct.unpack("<16f", packet[2:66])
                self._echo_pending = True
            else:
                # Look for a new signature inside the rejected bytes before dropping them.
                start = packet.find(SIGNATURE, 2)
                if start >= 0:
                    self._incoming.extend(packet[start:])

    def _echo(self) -> bytes:
        if not self._echo_pending or self.stored is None:
            return b""
        self._echo_pending = False
        v = self.stored
        softiron = (v[10], v[13], v[14], v[13], v[11], v[15], v[14], v[15], v[12])
        cal1 = ",".join(f"{x:.3f}" for x in v[:10])
        cal2 = ",".join(f"{x:.4f}" for x in softiron)
        return f"Cal1:{cal1}\r\nCal2:{cal2}\r\n".encode("ascii")
