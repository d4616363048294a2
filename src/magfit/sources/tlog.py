"""MAVLink telemetry logs (``.tlog``): the compass a ground station recorded while it was connected.

Mission Planner and QGroundControl write every MAVLink frame they receive to a ``.tlog``: a sequence of
records, each an 8-byte big-endian time stamp (microseconds since 1970, the ground station's clock when the
frame arrived) followed by one MAVLink frame::

    v1: 0xFE len seq sysid compid msgid         payload[len] crc[2]
    v2: 0xFD len incompat compat seq sysid compid msgid[3] payload[len] crc[2] (signature[13])

The checksum is X.25 (CRC-16/MCRF4XX) over the frame after its magic byte, then the message's CRC_EXTRA byte
(the MAVLink generator's hash of the message's definition: ``_MESSAGES`` below). MAVLink 2 drops the payload's
trailing zero bytes: they are put back. Fields are on the wire by size, largest first, then the extension
fields in the order they were added (``_LAYOUTS``). A radio link loses and damages bytes: frames whose checksum
is wrong are skipped, the reader resynchronises on the next frame whose checksum is right, and the bytes
skipped are counted in the source's notes. The whole file is scanned with NumPy (candidate magic bytes, then
every candidate's checksum at once); no Python loop runs per frame. pymavlink is deliberately not used: it
would be a dependency for six messages, and its ``magfit.py`` script shadows magfit's own command.

What ArduPilot streams (``libraries/GCS_MAVLink/GCS_Common.cpp``: ``send_raw_imu``, ``send_scaled_imu``):

- ``RAW_IMU`` (27): ``xmag, ymag, zmag`` = ``compass.get_field(0)``, ``SCALED_IMU2`` (116) and ``SCALED_IMU3``
  (129) = ``get_field(1)``, ``get_field(2)``: milligauss, **after** the firmware's calibration, in the body
  frame; ``get_field(i)`` is priority slot i (``_get_state(Priority(i))``, libraries/AP_Compass/AP_Compass.h),
  the same field and slot as DataFlash's ``MAG`` instance i. The calibration is undone exactly as for a
  DataFlash log (:func:`magfit.sources.ardupilot.undo_calibration`) with the ``COMPASS_*`` parameters the
  ground station fetched (``PARAM_VALUE``, 22). Without them the samples stay calibrated: a fit on them is a
  residual correction on top of the calibration in use, which the notes say.
- The same messages carry IMU i's accelerometer (``accel * 1000 / GRAVITY_MSS``: milli-g) and gyroscope
  (``gyro * 1000``: mrad/s), already rotated into the body frame: :meth:`Source.read_motion` takes them from
  the compass's own message, so they share its clock. ``RAW_IMU`` is stamped with ``micros64()``, the others
  with ``millis()``: both since boot.
- ``ATTITUDE`` (30): roll, pitch, yaw in radians, 3-2-1, body -> NED (as DataFlash's ATT).
- ``GPS_RAW_INT`` (24: lat/lon in 1e-7 degrees, alt in mm, fix_type >= 3 for a 3-D fix), else
  ``GLOBAL_POSITION_INT`` (33): the place for the World Magnetic Model; the date is the tlog's own.
- ``HIGHRES_IMU`` is left out for ArduPilot: ``send_highres_imu`` multiplies the milligauss field by 1000 under
  a "convert to gauss" comment (microgauss on the wire), and ``RAW_IMU`` carries the same compass.

PX4 streams ``HIGHRES_IMU`` (105): ``xmag..`` in gauss from ``vehicle_magnetometer``, calibrated and in the
body frame (src/modules/mavlink/streams/HIGHRES_IMU.hpp); it is read as calibrated samples (a residual fit).

Time: messages carry the vehicle's boot clock; the tlog's stamps carry the ground station's. Each message's
time is its boot stamp plus the median difference between the two clocks over its stretch of the log (a
reboot, the boot clock going back, starts a new stretch), so the compass, the attitude and the IMU keep the
vehicle's own spacing (no link jitter) on the station's UTC time line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFileError
from .ardupilot import (
    compass_mounting,
    compass_parameters,
    describe_parameters,
    first_value,
    undo_records,
    untrimmed,
)
from .detect import TLOG_STAMP_RANGE as _STAMP_RANGE  # (the format sniff: detect.is_tlog)
from .detect import is_tlog as is_tlog
from .motion import Motion, Stream, align, euler_quaternions
from .types import SLOW_RATE_HZ, LogSamples, Magnetometer, Position, Source, median_position

__all__ = ["TelemetryLog", "is_tlog", "open_tlog"]

# message id : CRC_EXTRA : payload length with every extension field, for every message of MAVLink's ``all``
# dialect (common, ardupilotmega, development ...), from the generated definitions (pymavlink 2.4,
# dialects/v20/all.py: ``crc_extra`` and ``unpacker.size``). Frames of other ids cannot be checked.
_TABLE = """
0:50:9 1:124:43 2:137:12 4:237:14 5:217:28 6:104:3 7:119:32 11:89:6 20:214:20 21:159:2 22:220:25 23:168:23
24:24:52 25:23:101 26:170:24 27:144:29 28:67:16 29:115:16 30:39:28 31:246:48 32:185:28 33:104:28 34:237:22
35:244:22 36:222:37 37:212:7 38:9:7 39:254:38 40:230:5 41:28:4 42:28:6 43:132:3 44:221:5 45:232:3 46:11:2
47:153:4 48:41:21 49:39:21 50:78:37 51:196:5 54:15:27 55:3:25 61:167:72 62:183:26 63:119:181 64:191:225
65:118:42 66:148:6 67:21:4 69:243:30 70:124:38 73:38:38 74:20:20 75:158:35 76:152:33 77:143:10 80:14:4
81:106:22 82:49:51 83:22:37 84:143:53 85:140:51 86:5:53 87:150:51 89:231:28 90:183:56 91:63:42 92:54:33
93:47:81 100:175:34 101:102:117 102:158:117 103:208:57 104:56:116 105:93:63 106:138:44 107:108:65 108:32:92
109:185:9 110:84:254 111:34:18 112:174:12 113:124:39 114:237:44 115:4:64 116:76:24 117:128:6 118:56:14
119:116:12 120:134:97 121:237:2 122:203:2 123:250:113 124:87:57 125:203:6 126:220:79 127:25:35 128:226:35
129:46:24 130:29:13 131:223:255 132:85:39 133:6:18 134:229:43 135:203:8 136:1:22 137:195:16 138:109:120
139:168:43 140:181:41 141:47:32 142:72:243 143:131:16 144:127:93 146:103:100 147:154:54 148:178:78
149:200:60 150:134:42 151:219:8 152:208:8 153:188:12 154:84:15 155:22:13 156:19:6 157:217:15 158:134:14
160:78:12 161:68:3 162:189:9 163:127:28 164:154:44 165:21:3 166:21:9 167:144:22 168:1:12 169:234:18
170:73:34 171:181:66 172:22:98 173:83:8 174:167:48 175:138:46 176:234:3 177:240:20 178:47:24 179:189:29
180:52:45 181:174:4 182:229:40 183:85:2 184:159:206 185:186:7 186:72:29 191:92:27 192:36:54 193:71:26
194:98:32 195:120:37 200:134:42 201:205:14 214:69:8 215:101:3 216:50:3 217:202:6 218:17:7 219:162:2
225:208:73 226:207:8 227:144:52 228:152:17 229:22:8 230:163:42 231:105:40 232:151:65 233:35:182 234:150:40
235:179:42 241:90:32 242:104:60 243:85:61 244:95:6 245:130:2 246:184:38 247:81:19 248:8:254 249:204:36
250:49:30 251:170:18 252:44:18 253:83:54 254:46:9 256:71:42 257:131:9 258:187:232 259:92:236 260:146:13
261:179:61 262:12:23 263:133:255 264:49:28 265:26:20 266:193:255 267:35:255 268:14:4 269:109:233 270:59:249
271:22:52 275:126:31 276:18:49 277:62:30 280:70:33 281:48:13 282:123:35 283:74:145 284:99:32 285:137:49
286:210:53 287:1:23 288:20:23 290:251:46 291:10:57 295:234:12 298:237:100 299:19:98 300:217:22 301:243:58
310:28:17 311:95:116 320:243:20 321:88:2 322:243:149 323:78:147 324:132:146 330:23:167 331:91:233 332:236:239
333:231:109 334:72:14 335:225:24 336:245:84 339:199:5 340:99:70 345:99:20 350:232:252 360:11:25 361:11:33
369:151:52 370:26:109 373:117:42 375:251:140 380:232:20 385:147:133 386:132:16 387:4:72 388:132:37 390:156:238
395:0:212 396:50:160 397:182:108 398:227:100 399:152:104 400:110:254 401:183:255 410:160:53 411:106:3
412:33:6 413:77:7 414:109:16 415:161:24 420:20:16 435:134:46 436:193:9 437:30:1 440:66:35 441:116:21 11000:134:52
11001:15:135 11002:234:179 11003:64:5 11010:46:49 11011:106:44 11020:205:16 11030:144:44 11031:133:44
11032:85:44 11033:195:37 11034:79:5 11035:128:8 11036:177:34 11037:130:28 11038:47:38 11039:142:9
12900:114:44 12901:254:59 12902:140:53 12903:249:46 12904:77:54 12905:49:43 12915:94:249 12918:139:51
12919:7:18 12920:20:5 42000:227:1 42001:239:46 50001:246:32 50002:181:246 50003:62:19 50004:240:17 50005:152:32
52000:13:100 52001:239:1 52002:84:1 52003:136:1 60000:95:26 60001:129:42 60002:121:16 60010:208:33
60011:123:38 60012:11:132 60013:75:47 60014:185:69 60015:212:69 60020:202:10 60021:138:13 60022:81:31
60023:150:8 60024:204:46 60025:79:47 60026:178:37 60027:24:40 60028:68:32 60029:231:24 60030:138:19
60031:41:63 60032:86:27 60033:155:17 60040:40:37 60041:145:249 60042:38:31 60043:75:30 60045:35:250
60047:6:28 60050:188:62 60051:222:40 60052:125:37 60053:7:200 60054:250:8 60055:149:39 60056:116:39
60057:236:39 60058:7:27 60059:240:2 60060:252:29
"""


def _message_table() -> tuple[NDArray[np.int64], NDArray[np.uint8], NDArray[np.int64]]:
    rows = np.array([[int(v) for v in item.split(":")] for item in _TABLE.split()], dtype=np.int64)
    return rows[:, 0], rows[:, 1].astype(np.uint8), rows[:, 2]


_IDS, _CRC_EXTRA, _MAX_LENGTH = _message_table()


def _layout(fields: str) -> np.dtype[Any]:
    """A payload's dtype from ``name:type`` pairs in wire order."""
    return np.dtype([tuple(item.split(":")) for item in fields.split()])


_IMU = " ".join(f"{axis}{what}:<i2" for what in ("acc", "gyro", "mag") for axis in "xyz")
#: The messages read, as laid out on the wire (largest fields first, then the extensions); each dtype's size is
#: the payload's full length in _TABLE (a test checks it).
_LAYOUTS: dict[int, tuple[str, np.dtype[Any]]] = {
    0: ("HEARTBEAT", _layout("custom_mode:<u4 type:u1 autopilot:u1 base_mode:u1 system_status:u1 mavlink_version:u1")),
    22: ("PARAM_VALUE", _layout("param_value:<f4 param_count:<u2 param_index:<u2 param_id:S16 param_type:u1")),
    24: (
        "GPS_RAW_INT",
        _layout(
            "time_usec:<u8 lat:<i4 lon:<i4 alt:<i4 eph:<u2 epv:<u2 vel:<u2 cog:<u2 fix_type:u1 satellites_visible:u1 "
            "alt_ellipsoid:<i4 h_acc:<u4 v_acc:<u4 vel_acc:<u4 hdg_acc:<u4 yaw:<u2"
        ),
    ),
    26: ("SCALED_IMU", _layout(f"time_boot_ms:<u4 {_IMU} temperature:<i2")),
    27: ("RAW_IMU", _layout(f"time_usec:<u8 {_IMU} id:u1 temperature:<i2")),
    30: ("ATTITUDE", _layout("time_boot_ms:<u4 roll:<f4 pitch:<f4 yaw:<f4 rollspeed:<f4 pitchspeed:<f4 yawspeed:<f4")),
    33: (
        "GLOBAL_POSITION_INT",
        _layout("time_boot_ms:<u4 lat:<i4 lon:<i4 alt:<i4 relative_alt:<i4 vx:<i2 vy:<i2 vz:<i2 hdg:<u2"),
    ),
    105: (
        "HIGHRES_IMU",
        _layout(
            "time_usec:<u8 "
            + " ".join(f"{axis}{what}:<f4" for what in ("acc", "gyro", "mag") for axis in "xyz")
            + " abs_pressure:<f4 diff_pressure:<f4 pressure_alt:<f4 temperature:<f4 fields_updated:<u2 id:u1"
        ),
    ),
    116: ("SCALED_IMU2", _layout(f"time_boot_ms:<u4 {_IMU} temperature:<i2")),
    129: ("SCALED_IMU3", _layout(f"time_boot_ms:<u4 {_IMU} temperature:<i2")),
    # The onboard compass calibration (ArduPilot's CompassCalibrator), read by magfit.sources.calibration_messages.
    191: (
        "MAG_CAL_PROGRESS",
        _layout(
            "direction_x:<f4 direction_y:<f4 direction_z:<f4 compass_id:u1 cal_mask:u1 cal_status:u1 attempt:u1 "
            "completion_pct:u1 completion_mask:10u1"
        ),
    ),
    192: (
        "MAG_CAL_REPORT",
        _layout(
            "fitness:<f4 ofs_x:<f4 ofs_y:<f4 ofs_z:<f4 diag_x:<f4 diag_y:<f4 diag_z:<f4 offdiag_x:<f4 offdiag_y:<f4 "
            "offdiag_z:<f4 compass_id:u1 cal_mask:u1 cal_status:u1 autosaved:u1 orientation_confidence:<f4 "
            "old_orientation:u1 new_orientation:u1 scale_factor:<f4"
        ),
    ),
    253: ("STATUSTEXT", _layout("severity:u1 text:S50 id:<u2 chunk_seq:u1")),
}
#: What a parameter's name is made of (ArduPilot's and PX4's names: letters, digits and underscores).
_NAME = re.compile(r"[A-Za-z0-9_]*")
_ID_OF = {name: msgid for msgid, (name, _) in _LAYOUTS.items()}

#: MAV_AUTOPILOT values (HEARTBEAT.autopilot).
_ARDUPILOT, _PX4 = 3, 12
#: MAV_MODE_FLAG_SAFETY_ARMED in HEARTBEAT.base_mode.
_ARMED = 128
#: A MAVLink time_usec above this (about 31 years) counts from 1970, not from boot (the MAVLink definition:
#: "the receiving end can infer timestamp format ... by checking for the magnitude of the number").
_EPOCH_USEC = 1_000_000_000_000_000
#: The vehicle's boot clock going back by more than this between two frames is a reboot: a new stretch, with its
#: own offset to the station's clock.
_REBOOT_S = 1.0
#: ArduPilot's GRAVITY_MSS, by which it divides the accelerometer to send milli-g (AP_Math/definitions.h).
_GRAVITY_MSS = 9.80665
#: Which priority slot each ArduPilot compass message carries (GCS_Common.cpp: get_field(0), (1), (2)).
_ARDUPILOT_SLOTS = {"RAW_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
_ALSO = ("ATTITUDE", "GPS_RAW_INT", "GLOBAL_POSITION_INT", "PARAM_VALUE", "HEARTBEAT", "HIGHRES_IMU", "SCALED_IMU")


def _magic_bytes(data: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Where 0xFE or 0xFD (a frame's first byte) occur, found 16 MiB at a time to bound the temporaries."""
    found = []
    chunk = 1 << 24
    for begin in range(0, len(data), chunk):
        piece = data[begin : begin + chunk]
        found.append(np.flatnonzero((piece - np.uint8(0xFD)) < 2).astype(np.int64) + begin)  # wraps below 0xFD
    return np.concatenate(found) if found else np.zeros(0, dtype=np.int64)


def _accumulate(crc: NDArray[np.uint16], byte: NDArray[Any]) -> NDArray[np.uint16]:
    """One byte of MAVLink's X.25 checksum (crc_accumulate in mavlink's checksum.h), for many frames at once."""
    tmp = (byte.astype(np.uint16) ^ (crc & 0xFF)) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)).astype(np.uint16, copy=False)


def x25_checksums(
    data: NDArray[np.uint8], first: NDArray[np.int64], span: NDArray[np.int64], extra: NDArray[np.uint8]
) -> NDArray[np.uint16]:
    """MAVLink's checksum of ``data[first[i] : first[i] + span[i]]`` followed by the byte ``extra[i]``, for
    every i. The frames are sorted by span, longest first, so that those still running at byte j are a prefix:
    one NumPy step per byte position, not per frame."""
    order = np.argsort(-span, kind="stable")
    first, span, extra = first[order], span[order], extra[order]
    crc = np.full(len(first), 0xFFFF, dtype=np.uint16)
    descending = -span  # ascending, for searchsorted
    for j in range(int(span[0]) + 1 if len(span) else 0):
        running = int(np.searchsorted(descending, -j, side="left"))  # frames with span > j
        ending = int(np.searchsorted(descending, -j, side="right"))  # ... and those whose span is j
        if running:
            crc[:running] = _accumulate(crc[:running], data[first[:running] + j])
        if ending > running:
            crc[running:ending] = _accumulate(crc[running:ending], extra[running:ending])
    checksums = np.empty_like(crc)
    checksums[order] = crc
    return checksums


#: Bytes read at a time: the scan's memory grows with this, not with the log.
_BLOCK = 1 << 22
#: The longest record: an 8-byte stamp, a MAVLink 2 header (10), a 255-byte payload, the checksum and a signature.
_MAX_RECORD = 8 + 10 + 255 + 2 + 13
#: Of each message (by system and component) at most this many frames are kept, a regular stride beyond (every
#: k-th, k doubled each time the count passes it): 2^17 compass samples are half a day at 3 Hz, and the memory
#: stays bounded (PARAM_VALUE is kept whole, its repeated values once: the parameters in effect never change).
#: A 1 GB tlog peaked at 376 MB with 2^18 (docs/scaling.md).
_KEPT = 1 << 17
#: Bytes between two frames with a right checksum beyond which the gap is counted as damage at once, not carried
#: over to be sorted (a file that is no tlog past its head, or a dialect this reader does not know).
_LONG_GAP = 1 << 20


class _Kept:
    """The frames kept of one message from one sender: payload rows, receive stamps and file order."""

    def __init__(self, width: int) -> None:
        self.width = width
        self.rows: list[NDArray[np.uint8]] = []
        self.receipt: list[NDArray[np.float64]] = []
        self.order: list[NDArray[np.int64]] = []
        self.index: list[NDArray[np.int64]] = []  # each frame's number among this message's, for the stride
        self.seen = 0
        self.every = 1
        self.kept = 0

    def add(self, rows: NDArray[np.uint8], receipt: NDArray[np.float64], order: NDArray[np.int64], thin: bool) -> None:
        index = np.arange(self.seen, self.seen + len(rows), dtype=np.int64)  # (int64: a log may hold > 2^31)
        self.seen += len(rows)
        chosen = index % self.every == 0 if thin else slice(None)
        self.rows.append(rows[chosen])
        self.receipt.append(receipt[chosen])
        self.order.append(order[chosen])
        self.index.append(index[chosen])
        self.kept += len(self.index[-1])
        while thin and self.kept > _KEPT:  # every second one of those kept, and so on from here
            self.every *= 2
            mask = [i % self.every == 0 for i in self.index]
            for name in ("rows", "receipt", "order", "index"):
                parts = getattr(self, name)
                setattr(self, name, [part[m] for part, m in zip(parts, mask, strict=True)])
            self.kept = sum(len(i) for i in self.index)

    def arrays(self) -> tuple[NDArray[np.uint8], NDArray[np.float64], NDArray[np.int64]]:
        """The frames kept, in one array each; the pieces are let go (read once: they held as much again)."""
        if not self.rows:
            return np.zeros((0, self.width), np.uint8), np.zeros(0), np.zeros(0, np.int64)
        whole = np.concatenate(self.rows), np.concatenate(self.receipt), np.concatenate(self.order)
        self.rows, self.receipt, self.order, self.index = [], [], [], []
        return whole


class TelemetryLog:
    """A tlog scanned once, in blocks: the frames whose checksum is right of the messages magfit reads, with
    their source, message id and time stamp; of every other frame, its count and sequence number.

    The file is read :data:`_BLOCK` bytes at a time (a block's last record, perhaps cut by the block's end,
    is read again with the next), so the memory does not grow with the log: of each message read, at most
    :data:`_KEPT` frames a sender are kept (a regular stride beyond, said in the compass's notes); of
    PARAM_VALUE every change of a value.

    Parameters
    ----------
    path : Path
        The name messages give.
    data : bytes or Path
        The file's bytes, or the file to read them from (in blocks).
    also : mapping of int to int, optional
        Other messages to keep (message id: the payload's full length), read with :meth:`messages_of`.

    Raises
    ------
    DataFileError
        Not one frame with a right checksum.
    """

    def __init__(self, path: Path, data: bytes | Path, *, also: dict[int, int] | None = None) -> None:
        self.path = path
        self.skipped_bytes = 0  # bytes in no frame whose checksum is right
        #: (system, component, message id) -> (frames, bytes) of well-formed frames none of which passed its
        #: checksum: another definition of the message (a dialect or version this reader does not share)
        self.unchecked: dict[tuple[int, int, int], tuple[int, int]] = {}
        self.truncated = False
        self.bad_stamps = 0
        self.thinned: dict[tuple[int, int, int], int] = {}  # (system, component, message id) -> every k-th kept
        self._widths = {msgid: dtype.itemsize for msgid, (_, dtype) in _LAYOUTS.items()}
        self._widths.update(also or {})
        self._kept: dict[tuple[int, int, int], _Kept] = {}
        self._counts: dict[tuple[int, int, int], int] = {}
        self._last_seq: dict[tuple[int, int], int] = {}
        self._lost: dict[tuple[int, int], int] = {}
        self._passed: set[int] = set()
        self._parameters_seen: dict[tuple[int, int], dict[bytes, int]] = {}
        self._listed: dict[tuple[int, int], set[int]] = {}
        self._param_counts: dict[tuple[int, int], dict[int, int]] = {}
        self._frames = 0
        self._read(data)
        self._assemble()
        if not self._frames:
            raise DataFileError(
                f"{path}: starts like a MAVLink telemetry log (.tlog) but holds no MAVLink frame whose checksum is "
                "right: the file is damaged, or is not a tlog"
            )

    # -------------------------------------------------------------------------------------------- the scan

    def _read(self, data: bytes | Path) -> None:
        handle: BinaryIO
        if isinstance(data, Path):
            try:
                handle = open(data, "rb")
            except OSError as error:
                raise DataFileError(
                    f"{self.path}: cannot be read ({error.strerror}); check the file's permissions"
                ) from None
        else:
            import io

            handle = io.BytesIO(data)
        with handle:
            carry = b""
            while True:
                block = handle.read(_BLOCK)
                eof = not block
                buffer = carry + block
                if not buffer:
                    break
                used = self._scan(np.frombuffer(buffer, dtype=np.uint8), eof)
                carry = buffer[used:]
                if eof:
                    break
        # Frames whose checksum failed while others of the same message from the same sender passed are damage;
        # a message none of whose frames passes is sent with a definition this reader does not share.
        for key, (_, size_sum) in list(self.unchecked.items()):
            if (key[0] << 32) | (key[1] << 24) | key[2] in self._passed:
                self.skipped_bytes += size_sum
                del self.unchecked[key]

    def _scan(self, data: NDArray[np.uint8], eof: bool) -> int:
        """Scan ``data`` (the bytes carried over, then a block): keep the frames whose record starts where no
        record can run past the end of ``data`` (all at the end of the file), sort the gaps between them, and
        return where the next scan starts (the end of the last frame kept, or past a long gap)."""
        n = len(data)
        candidate = _magic_bytes(data)
        candidate = candidate[(candidate >= 8) & (candidate + 10 <= n)]  # a stamp before, a v2 header after
        v2 = data[candidate] == 0xFD
        length = data[candidate + 1].astype(np.int64)
        incompat = np.where(v2, data[candidate + 2], 0)
        msgid = np.where(
            v2,
            data[candidate + 7].astype(np.int64)
            | (data[candidate + 8].astype(np.int64) << 8)
            | (data[candidate + 9].astype(np.int64) << 16),
            data[candidate + 5],
        )
        where = np.clip(np.searchsorted(_IDS, msgid), 0, len(_IDS) - 1)
        header = np.where(v2, 10, 6)
        size = header + length + 2 + np.where(incompat & 1, 13, 0)  # the signature follows the checksum
        check = (_IDS[where] == msgid) & (length >= 1) & (length <= _MAX_LENGTH[where]) & (incompat <= 1)
        check &= candidate + size <= n
        candidate, v2, length, msgid, where, header, size = (
            a[check] for a in (candidate, v2, length, msgid, where, header, size)
        )
        end = candidate + header + length
        sent = data[end].astype(np.uint16) | (data[end + 1].astype(np.uint16) << 8)
        ok = x25_checksums(data, candidate + 1, header + length - 1, _CRC_EXTRA[where]) == sent
        # A right checksum inside another frame is a coincidence (1 in 65 536): the earlier frame wins.
        index = np.flatnonzero(ok)
        ends = candidate[index] + size[index]
        before = np.concatenate([[0], np.maximum.accumulate(ends)[:-1]]) if len(index) else ends
        index = index[candidate[index] - 8 >= before]
        limit = n if eof else n - _MAX_RECORD  # a record starting later may run past the block: read it again
        index = index[candidate[index] - 8 < limit]
        used = int(candidate[index[-1]] + size[index[-1]]) if len(index) else 0
        if not eof and limit - used > _LONG_GAP:
            used = limit  # no frame for so long: damage (counted by _account), not carried over
        c = candidate[index]
        self._account(data, c - 8, c + size[index], n if eof else used, eof)
        stamps = np.zeros(len(index), dtype=np.uint64)
        for byte in range(8):  # big-endian
            stamps = (stamps << np.uint64(8)) | data[c - 8 + byte].astype(np.uint64)
        plausible = (stamps >= _STAMP_RANGE[0]) & (stamps <= _STAMP_RANGE[1])
        self.bad_stamps += int(np.count_nonzero(~plausible))
        index, stamps, c = index[plausible], stamps[plausible], c[plausible]
        v2 = v2[index]
        sysid = np.where(v2, data[c + 5], data[c + 3]).astype(np.int64)
        compid = np.where(v2, data[c + 6], data[c + 4]).astype(np.int64)
        seq = np.where(v2, data[c + 4], data[c + 2]).astype(np.int64)
        ids = msgid[index]
        self._tally(sysid, compid, ids, seq)
        payload, lengths = c + header[index], length[index]
        order = np.arange(self._frames, self._frames + len(index), dtype=np.int64)
        self._frames += len(index)
        receipt = stamps.astype(np.float64) / 1e6
        for msgid_kept, width in self._widths.items():
            mine = np.flatnonzero(ids == msgid_kept)
            if not len(mine):
                continue
            rows = _payload_rows(data, payload[mine], lengths[mine], width)
            for source in set(zip(sysid[mine].tolist(), compid[mine].tolist(), strict=True)):
                who = mine[(sysid[mine] == source[0]) & (compid[mine] == source[1])]
                at = np.searchsorted(mine, who)
                chosen_rows = rows[at]
                if msgid_kept == _ID_OF["PARAM_VALUE"]:
                    keep = self._parameter_changes(source, chosen_rows)
                    who, chosen_rows = who[keep], chosen_rows[keep]
                key = (source[0], source[1], msgid_kept)
                kept = self._kept.get(key)
                if kept is None:
                    kept = self._kept[key] = _Kept(width)
                kept.add(chosen_rows, receipt[who], order[who], thin=msgid_kept != _ID_OF["PARAM_VALUE"])
        return used

    def _tally(
        self, sysid: NDArray[np.int64], compid: NDArray[np.int64], ids: NDArray[np.int64], seq: NDArray[np.int64]
    ) -> None:
        """Every frame's count by sender and message, the link's losses from the sequence numbers, and which
        (sender, message) pairs passed a checksum."""
        keys = (sysid << 32) | (compid << 24) | ids
        unique, counts = np.unique(keys, return_counts=True)
        self._passed.update(unique.tolist())
        for key, count in zip(unique.tolist(), counts.tolist(), strict=True):
            triple = (key >> 32, (key >> 24) & 0xFF, key & 0xFFFFFF)
            self._counts[triple] = self._counts.get(triple, 0) + count
        for source in set(zip(sysid.tolist(), compid.tolist(), strict=True)):
            mine = seq[(sysid == source[0]) & (compid == source[1])]
            last = self._last_seq.get(source)
            if last is not None:
                mine = np.concatenate([[last], mine])
            step = np.diff(mine) % 256
            self._lost[source] = self._lost.get(source, 0) + int(np.sum(step[step > 0] - 1))  # 0: recorded twice
            self._last_seq[source] = int(mine[-1])

    def _parameter_changes(self, source: tuple[int, int], rows: NDArray[np.uint8]) -> NDArray[np.bool_]:
        """Which PARAM_VALUE frames say something new (a name's first value, or a changed one); the indices
        and counts of every frame kept for :meth:`parameter_list_complete`."""
        records = rows.view(_LAYOUTS[_ID_OF["PARAM_VALUE"]][1]).reshape(-1)
        listed = records["param_index"] != 65535  # 65535 marks a value set, not listed
        self._listed.setdefault(source, set()).update(np.unique(records["param_index"][listed]).tolist())
        counts = self._param_counts.setdefault(source, {})
        for count, times in zip(*np.unique(records["param_count"][listed], return_counts=True), strict=True):
            counts[int(count)] = counts.get(int(count), 0) + int(times)
        seen = self._parameters_seen.setdefault(source, {})
        names, values = records["param_id"], records["param_value"].view(np.uint32)
        order = np.argsort(names, kind="stable")  # by name, each name's frames in log order
        names, values = names[order], values[order]
        first = np.ones(len(names), dtype=bool)
        first[1:] = names[1:] != names[:-1]
        changed = first.copy()
        changed[1:] |= values[1:] != values[:-1]
        starts = np.flatnonzero(first)
        for at, last in zip(starts.tolist(), [*(starts[1:] - 1).tolist(), len(names) - 1], strict=True):
            name = bytes(names[at])
            if seen.get(name) == int(values[at]):
                changed[at] = False  # the value already in effect, sent again
            seen[name] = int(values[last])
        keep = np.zeros(len(records), dtype=bool)
        keep[order[changed]] = True
        return keep

    def _account(
        self, data: NDArray[np.uint8], starts: NDArray[np.int64], ends: NDArray[np.int64], stop: int, eof: bool
    ) -> None:
        """Sort the bytes between accepted records (up to ``stop``): a gap that well-formed frames fill exactly
        holds frames whose checksum failed (damage, or ``unchecked`` when no frame of that message from that
        sender passed); otherwise it is damage, or a last record cut short."""
        n = len(data)
        begins = np.concatenate([[0], ends])
        finish = np.concatenate([starts, [stop]])
        gaps = np.flatnonzero(finish > begins)
        for g in gaps.tolist():
            pos, end = int(begins[g]), int(finish[g])
            if g == len(starts) and not eof:  # bytes up to a scan's stop that no frame starts in for _LONG_GAP
                self.skipped_bytes += end - pos
                continue
            found = []
            while (frame := _frame_at(data, pos + 8, end)) is not None:
                found.append(frame)
                pos += 8 + frame[0]
            if pos == end:
                for size, key in found:
                    frames, size_sum = self.unchecked.get(key, (0, 0))
                    self.unchecked[key] = (frames + 1, size_sum + size + 8)
                continue
            if eof and end == n and n - pos < _MAX_RECORD and (pos + 8 >= n or data[pos + 8] in (0xFE, 0xFD)):
                self.truncated = True  # the log was not closed: its last record is cut short
                continue
            self.skipped_bytes += int(end - begins[g])

    def _assemble(self) -> None:
        """The frames kept, in file order: their sender, message, receive stamp, and where their payload is."""
        empty = (np.int64, np.float64, np.uint8, np.uint8, np.int32, np.int32)
        parts: list[tuple[NDArray[Any], ...]] = [tuple(np.zeros(0, dtype=kind) for kind in empty)]
        self._rows: dict[tuple[int, int, int], NDArray[np.uint8]] = {}
        while self._kept:  # each message's pieces let go as soon as they are joined
            key, kept = self._kept.popitem()
            rows, receipt, order = kept.arrays()
            self._rows[key] = rows
            if kept.every > 1:
                self.thinned[key] = kept.every
            parts.append((order, receipt, np.full(len(order), key[0], np.uint8), np.full(len(order), key[1], np.uint8),
                          np.full(len(order), key[2], np.int32), np.arange(len(order), dtype=np.int32)))  # fmt: skip
        order, receipt, sysid, compid, msgid, row = (np.concatenate(p) for p in zip(*parts, strict=True))
        sort = np.argsort(order, kind="stable")
        del order
        self.receipt_s = receipt[sort]
        self.sysid, self.compid, self.msgid = sysid[sort], compid[sort], msgid[sort]
        self._row = row[sort]

    # ------------------------------------------------------------------------------------------ the frames

    def sources(self) -> list[tuple[int, int]]:
        """The (system id, component id) pairs that sent frames, most frames first."""
        totals: dict[tuple[int, int], int] = {}
        for (system, component, _), count in self._counts.items():
            totals[(system, component)] = totals.get((system, component), 0) + count
        return sorted(totals, key=lambda source: (-totals[source], source))

    def counts(self, source: tuple[int, int]) -> dict[int, int]:
        """Message id -> number of frames from ``source`` (every frame, kept or not)."""
        return {msgid: count for (s, c, msgid), count in sorted(self._counts.items()) if (s, c) == source}

    def frames(self, name: str, source: tuple[int, int]) -> NDArray[np.int64]:
        """Indices (into the frames kept, in file order) of message ``name`` from ``source``."""
        return self.frames_of(_ID_OF[name], source)

    def frames_of(self, msgid: int, source: tuple[int, int]) -> NDArray[np.int64]:
        """As :meth:`frames`, by message id."""
        mine = (self.msgid == msgid) & (self.sysid == source[0]) & (self.compid == source[1])
        return np.flatnonzero(mine)

    def messages(self, name: str, frames: NDArray[np.int64]) -> NDArray[Any]:
        """The payloads of ``frames`` (all of message ``name``) as a structured array, the zeros MAVLink 2
        dropped from their ends put back."""
        return self.messages_of(frames, _LAYOUTS[_ID_OF[name]][1])

    def messages_of(self, frames: NDArray[np.int64], dtype: np.dtype[Any]) -> NDArray[Any]:
        """As :meth:`messages`, for the frames of one message kept with ``also``, laid out as ``dtype``."""
        if not len(frames):
            return np.zeros(0, dtype=dtype)
        key = (int(self.sysid[frames[0]]), int(self.compid[frames[0]]), int(self.msgid[frames[0]]))
        rows = self._rows[key][self._row[frames], : dtype.itemsize]
        return np.ascontiguousarray(rows).view(dtype).reshape(-1)

    def parameter_list_complete(self, source: tuple[int, int]) -> bool:
        """Whether every index below PARAM_VALUE's ``param_count`` came from ``source``."""
        counts = self._param_counts.get(source, {})
        if not counts:
            return False
        usual = max(counts, key=lambda count: (counts[count], -count))
        return len(self._listed.get(source, ())) >= usual

    def lost_share(self, source: tuple[int, int]) -> float:
        """The share of ``source``'s frames the link lost, from the gaps in their sequence numbers."""
        seen = sum(count for (s, c, _), count in self._counts.items() if (s, c) == source)
        if seen < 2:
            return 0.0
        lost = self._lost.get(source, 0)
        return lost / (lost + seen)


def _frame_at(data: NDArray[np.uint8], pos: int, end: int) -> tuple[int, tuple[int, int, int]] | None:
    """The size and (system, component, message id) of a well-formed frame header at ``pos`` whose frame ends
    by ``end``, whatever its checksum; None when there is none."""
    if pos + 10 > end or data[pos] not in (0xFE, 0xFD):
        return None
    if data[pos] == 0xFE:
        key = (int(data[pos + 3]), int(data[pos + 4]), int(data[pos + 5]))
        size = int(data[pos + 1]) + 8
    elif data[pos + 2] <= 1:
        key = (
            int(data[pos + 5]),
            int(data[pos + 6]),
            int(data[pos + 7]) | int(data[pos + 8]) << 8 | int(data[pos + 9]) << 16,
        )
        size = int(data[pos + 1]) + 12 + (13 if data[pos + 2] & 1 else 0)
    else:
        return None
    return (size, key) if pos + size <= end else None


def _payload_rows(
    data: NDArray[np.uint8], payload: NDArray[np.int64], length: NDArray[np.int64], width: int
) -> NDArray[np.uint8]:
    """The payloads at ``payload`` (``length`` bytes each) as rows of ``width`` bytes, the zeros MAVLink 2
    dropped from their ends put back."""
    rows = np.zeros((len(payload), width), dtype=np.uint8)
    length = np.minimum(length, width)
    for sent in np.unique(length).tolist():  # a few lengths per message: one gather of whole rows each
        which = np.flatnonzero(length == sent)
        rows[which, :sent] = np.lib.stride_tricks.sliding_window_view(data, sent)[payload[which]]
    return rows


@dataclass(frozen=True)
class _Vehicle:
    """One system's frames read: its messages, its clock and its parameters."""

    log: TelemetryLog
    source: tuple[int, int]
    autopilot: int | None
    clock: NDArray[np.float64]  # per accepted frame: UTC seconds on the vehicle's clock (else its receive time)
    stretches: int
    parameters: dict[str, list[tuple[float, float]]]
    complete: bool  # the whole parameter list came: a parameter it lacks is one the firmware did not have
    armed: tuple[NDArray[np.float64], NDArray[np.bool_]]  # HEARTBEAT times and armed flags

    def records(self, name: str) -> tuple[NDArray[Any], NDArray[np.float64]]:
        frames = self.log.frames(name, self.source)
        return self.log.messages(name, frames), self.clock[frames]


def _boot_seconds(name: str, records: NDArray[Any]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """A message's own stamps in seconds, and which of them count from 1970 rather than from boot."""
    if "time_usec" in (records.dtype.names or ()):
        usec = records["time_usec"]
        return usec.astype(np.float64) / 1e6, usec >= _EPOCH_USEC
    return records["time_boot_ms"].astype(np.float64) / 1e3, np.zeros(len(records), dtype=bool)


def _vehicle_clock(log: TelemetryLog, source: tuple[int, int]) -> tuple[NDArray[np.float64], int]:
    """Per frame, its time on the vehicle's clock set to UTC by the station's receive stamps (module docstring);
    frames without a boot stamp get their receive stamp. Also the number of stretches (reboots + 1)."""
    clock = log.receipt_s.copy()
    frames_list, boot_list = [], []
    for name in (
        "RAW_IMU",
        "SCALED_IMU",
        "SCALED_IMU2",
        "SCALED_IMU3",
        "HIGHRES_IMU",
        "ATTITUDE",
        "GLOBAL_POSITION_INT",
    ):
        frames = log.frames(name, source)
        if not len(frames):
            continue
        boot, epoch = _boot_seconds(name, log.messages(name, frames))
        clock[frames[epoch]] = boot[epoch]  # already UTC (a companion computer's or a synced PX4's stamps)
        frames_list.append(frames[~epoch])
        boot_list.append(boot[~epoch])
    if not frames_list:
        return clock, 0
    frames = np.concatenate(frames_list)
    order = np.argsort(frames, kind="stable")
    frames, boot = frames[order], np.concatenate(boot_list)[order]
    difference = log.receipt_s[frames] - boot
    # A new stretch where the boot clock goes back (a reboot). The receive stamps are not checked by any
    # checksum: a damaged one is outvoted by the median, never followed.
    breaks = np.flatnonzero(np.diff(boot) < -_REBOOT_S) + 1
    stretch = np.zeros(len(boot), dtype=np.int64)
    stretch[breaks] = 1
    stretch = np.cumsum(stretch)
    offsets = np.array([np.median(part) for part in np.split(difference, breaks)])
    clock[frames] = boot + offsets[stretch]
    return clock, int(stretch[-1]) + 1 if len(stretch) else 0


def _parameters(log: TelemetryLog, source: tuple[int, int]) -> tuple[dict[str, list[tuple[float, float]]], bool]:
    """PARAM_VALUE: name -> [(receive time, value), ...] in log order (as DataFlashLog.parameters gives them),
    and whether the list is complete (every index below param_count came), so that a parameter it lacks is one
    the firmware did not have (COMPASS_DIA/ODI before Copter 3.3: no matrix). ArduPilot sends every value as a
    float cast (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST), integers too."""
    frames = log.frames("PARAM_VALUE", source)
    records = log.messages("PARAM_VALUE", frames)
    table: dict[str, list[tuple[float, float]]] = {}
    values = records["param_value"].astype(np.float64)
    for name, value, time in zip(records["param_id"], values, log.receipt_s[frames], strict=True):
        # The name ends at its first byte outside a parameter name's letters: old firmwares sent stack bytes after
        # the NUL, or in place of it after a 15-letter name (dronekit's test.tlog: b"COMPASS_AUTODEC\xdf").
        text = _NAME.match(name.decode("latin-1"))
        table.setdefault(text.group(0) if text else "", []).append((float(time), float(value)))
    # The whole list was downloaded when every index below param_count came (65535 marks a value set, not listed).
    return table, log.parameter_list_complete(source)


def _vehicle(log: TelemetryLog, source: tuple[int, int]) -> _Vehicle:
    clock, stretches = _vehicle_clock(log, source)
    beats = log.messages("HEARTBEAT", log.frames("HEARTBEAT", source))
    autopilots = beats["autopilot"][beats["autopilot"] != 8]  # 8: MAV_AUTOPILOT_INVALID (not a flight controller)
    autopilot = int(np.bincount(autopilots).argmax()) if len(autopilots) else None
    frames = log.frames("HEARTBEAT", source)
    armed = (log.receipt_s[frames], (beats["base_mode"] & _ARMED) != 0)
    parameters, complete = _parameters(log, source)
    return _Vehicle(log, source, autopilot, clock, stretches, parameters, complete, armed)


def open_tlog(path: Path, file: Path) -> Source:
    """Read a MAVLink telemetry log into a :class:`~magfit.sources.Source` (``file``: its bytes on disk, read in
    blocks by :class:`TelemetryLog`: the memory does not grow with the log)."""
    return source_from_tlog(path, TelemetryLog(path, file))


def _compass_messages(vehicle: _Vehicle) -> list[str]:
    counts = vehicle.log.counts(vehicle.source)
    if vehicle.autopilot == _PX4:
        return [name for name in ("HIGHRES_IMU",) if counts.get(_ID_OF[name])]
    return [name for name in _ARDUPILOT_SLOTS if counts.get(_ID_OF[name])]


def source_from_tlog(path: Path, log: TelemetryLog) -> Source:
    """The :class:`~magfit.sources.Source` of a scanned tlog: the compasses of every system that sent one."""
    vehicles = [_vehicle(log, source) for source in log.sources()]
    with_compass = [v for v in vehicles if _compass_messages(v)]
    chosen = with_compass or [v for v in vehicles if v.autopilot not in (None, 0)][:1] or vehicles[:1]
    several = len(chosen) > 1
    main = chosen[0] if chosen else None  # the system that sent the most frames: its position, its messages
    compasses: dict[str, _Compass] = {}
    for vehicle in sorted(chosen, key=lambda v: v.source):
        for name in _compass_messages(vehicle):
            sensor = f"{name}@{vehicle.source[0]}.{vehicle.source[1]}" if several else name
            compasses[sensor] = _Compass(vehicle, name, sensor)
    magnetometers = [c.magnetometer for c in compasses.values()]
    if not compasses:
        magnetometers.append(_missing(chosen[0] if chosen else None))
    notes = _file_notes(log, chosen)
    other: tuple[str, ...] = ()
    if main is not None:
        counts = log.counts(main.source)
        names = {msgid: name for msgid, (name, _) in _LAYOUTS.items()}
        used = {c.name for c in compasses.values()}
        other = tuple(f"{n} ({counts[_ID_OF[n]]})" for n in _ALSO if counts.get(_ID_OF[n]) and n not in used)
        rest = sum(1 for msgid in counts if msgid not in names)
        if rest:
            other += (f"{rest} other message types",)
    position = _position(main) if main is not None else None

    def read(magnetometer: Magnetometer) -> LogSamples:
        return compasses[magnetometer.id].read()

    def motion(magnetometer: Magnetometer) -> Motion:
        return compasses[magnetometer.id].motion(position)

    return Source(
        path=path,
        kind="tlog",
        format="MAVLink telemetry log (.tlog"
        + (f", {_AUTOPILOTS.get(main.autopilot, 'autopilot')}" if main and main.autopilot in _AUTOPILOTS else "")
        + ")",
        time_base="seconds since the epoch (the vehicle's clock, set by the ground station's receive times)",
        magnetometers=tuple(magnetometers),
        other=other,
        notes=tuple(notes),
        position=position,
        _reader=read,
        _motion=motion,
    )


_AUTOPILOTS = {_ARDUPILOT: "ArduPilot", _PX4: "PX4"}


def _file_notes(log: TelemetryLog, vehicles: list[_Vehicle]) -> list[str]:
    notes = []
    if log.skipped_bytes:
        notes.append(
            f"{log.skipped_bytes} bytes skipped as damaged (no frame with a right checksum starts there): bytes the "
            "link garbled or dropped, or a sender's broken frames"
        )
    if log.unchecked:
        listed = sorted(log.unchecked.items(), key=lambda item: -item[1][0])
        said = ", ".join(
            f"{frames} of message {k[2]} from system {k[0]} component {k[1]}" for k, (frames, _) in listed[:4]
        )
        notes.append(
            f"frames whose checksum never matches MAVLink's definition of their message ({said}"
            + (f" and {len(listed) - 4} more" if len(listed) > 4 else "")
            + "): their sender uses another dialect or version of it; passed over"
        )
    if log.bad_stamps:
        notes.append(f"{log.bad_stamps} frames dropped: their tlog time stamp is not a date (a damaged record)")
    if log.truncated:
        notes.append("the last record is cut short (the ground station did not close the log): it is ignored")
    for vehicle in vehicles:
        lost = log.lost_share(vehicle.source)
        if lost > 0.01:
            notes.append(
                f"the link lost about {100 * lost:.0f} % of system {vehicle.source[0]}'s frames (gaps in their "
                "sequence numbers)"
            )
        if vehicle.stretches > 1:
            notes.append(
                f"system {vehicle.source[0]}'s clock restarted {vehicle.stretches - 1} time(s) (a reboot): each "
                "stretch is placed on the station's clock by itself"
            )
    return notes


def _missing(vehicle: _Vehicle | None) -> Magnetometer:
    """A placeholder that says what to stream when the tlog holds no compass message."""
    if vehicle is not None and vehicle.autopilot == _PX4:
        what = "HIGHRES_IMU (PX4: `mavlink stream -d <port> -s HIGHRES_IMU -r 10` on the vehicle's console)"
    else:
        what = (
            "RAW_IMU (ArduPilot: set SR0_RAW_SENS, or SRn_RAW_SENS for the telemetry port the ground station uses, "
            "to 10 Hz; Mission Planner: Config, Planner, Telemetry Rates, Sensor)"
        )
    return Magnetometer(
        id="RAW_IMU",
        description="no compass message",
        unit="mG",
        n_samples=0,
        problem=f"the ground station recorded no compass message: stream {what} and record again",
    )


class _Compass:
    """One compass message of one system: what it is, and how its samples are read."""

    def __init__(self, vehicle: _Vehicle, name: str, sensor: str) -> None:

        self.vehicle, self.name, self.sensor = vehicle, name, sensor
        self.every = vehicle.log.thinned.get((*vehicle.source, _ID_OF[name]), 1)
        frames = vehicle.log.frames(name, vehicle.source)
        records, time = vehicle.log.messages(name, frames), vehicle.clock[frames]
        _, first = np.unique(time, return_index=True)  # a frame recorded twice (two links): once
        keep = np.zeros(len(records), dtype=bool)
        keep[first] = True
        mag = np.column_stack([records[f"{axis}mag"] for axis in "xyz"]).astype(np.float64)
        zero = np.all(mag == 0, axis=1)  # no compass in this slot, or not yet read
        self.n_zero = int(np.count_nonzero(zero & keep))
        keep &= ~zero & np.all(np.isfinite(mag), axis=1) & np.isfinite(time)
        order = np.argsort(time[keep], kind="stable")
        self.records, self.time = records[keep][order], time[keep][order]
        self.receipt = vehicle.log.receipt_s[frames][keep][order]  # the station's clock, as HEARTBEAT's
        self.mag = mag[keep][order]
        self.px4 = vehicle.autopilot == _PX4
        self.slot = None if self.px4 else _ARDUPILOT_SLOTS[name]
        self.unit = "G" if self.px4 else "mG"
        notes: list[str] = []
        problem: str | None = None
        in_use: str | None = None  # the firmware's calibration left in the samples (a residual fit)
        self.compass: Any = None
        if vehicle.autopilot not in (_ARDUPILOT, _PX4):
            notes.append("no HEARTBEAT names the autopilot: read as ArduPilot's (the firmware that streams RAW_IMU)")
        if self.px4:
            in_use = "PX4's HIGHRES_IMU field, already calibrated with CAL_MAGn_*"
            notes.append(
                "HIGHRES_IMU's field is PX4's vehicle_magnetometer: calibrated with CAL_MAGn_* and in the body frame; "
                "it is not undone, so a fit on it is a residual correction on top of the calibration in use (its "
                "offset adds to CAL_MAGn_*OFF, not replaces it)"
            )
        elif not any(key.startswith("COMPASS_OFS") for key in vehicle.parameters):
            in_use = f"ArduPilot's {name} field, already calibrated, and no COMPASS_* parameters in the log to undo it"
            notes.append(
                f"{name}'s field is ArduPilot's calibrated field and the ground station fetched no COMPASS_* "
                "parameters while recording, so the calibration in use cannot be undone: a fit on these samples is a "
                "residual correction on top of it (its offset adds to COMPASS_OFS*, its matrix multiplies DIA/ODI), "
                "not a calibration to write in their place; connect until the parameters are downloaded and record "
                "again for a full calibration"
            )
        else:
            first_time = float(self.time[0]) if len(self.time) else float("nan")
            assert self.slot is not None
            # A list the station did not download whole may lack a parameter the firmware has: only a complete one
            # says what the firmware did not have (as a DataFlash log's PARM messages, which hold them all).
            self.compass, problem = compass_parameters(
                vehicle.parameters, self.slot, first_time, absent_means_default=vehicle.complete
            )
            if self.compass is not None:
                said = describe_parameters(self.compass, "from the parameters the ground station fetched (PARAM_VALUE)")
                notes.append(f"{name}'s xmag/ymag/zmag are ArduPilot's field after its calibration; {said[0]}")
                notes.extend(said[1:])
                problem = self._motor_compensation(notes)
            elif problem is not None:  # dataflash's words are for PARM messages: say it for a tlog
                problem = problem.replace(
                    "the log's PARM messages lack", "the parameters the ground station fetched (PARAM_VALUE) lack"
                ).replace(
                    "log the parameters (ArduPilot writes them at the start of every log)",
                    "let the ground station download every parameter while recording (Mission Planner: Config, Full "
                    "Parameter List, Refresh Params)",
                )
        if self.n_zero:
            notes.append(f"{self.n_zero} samples of exactly (0, 0, 0) dropped (no reading in that slot)")
        if not len(self.time) and problem is None:
            problem = f"every {name} sample is (0, 0, 0): the vehicle has no compass in that slot"
        self.notes = notes
        self.magnetometer = Magnetometer(
            id=sensor,
            description=self._description(),
            unit=self.unit,
            n_samples=len(self.time),
            start_s=float(self.time[0]) if len(self.time) else float("nan"),
            end_s=float(self.time[-1]) if len(self.time) else float("nan"),
            device_id=self.compass.device_id if self.compass is not None else None,
            raw=False,
            notes=tuple(notes),
            problem=problem,
            slot=self.compass.index if self.compass is not None else self.slot,
            calibration_in_use=in_use,
        )
        rate = self.magnetometer.rate_hz
        if np.isfinite(rate) and rate < SLOW_RATE_HZ:
            notes.append(
                f"streamed at only {rate:.1f} Hz: too slow for a fit over a short tumble; "
                + (
                    "stream HIGHRES_IMU faster (mavlink stream -r 10)"
                    if self.px4
                    else "set SR0_RAW_SENS (or the SRn_RAW_SENS of the ground station's port) to 10 Hz or more"
                )
            )
            self.magnetometer = replace(self.magnetometer, notes=tuple(notes))

    def _description(self) -> str:
        what = "PX4 vehicle_magnetometer" if self.px4 else f"compass {self.slot + 1 if self.slot is not None else ''}"
        device = ""
        if self.compass is not None and self.compass.device_id:
            s = "" if self.compass.index == 0 else str(self.compass.index + 1)
            device = f", COMPASS_DEV_ID{s} {self.compass.device_id}"
        return f"{what} ({self.name}{device})"

    def _motor_compensation(self, notes: list[str]) -> str | None:
        """A tlog does not carry the motor compensation ArduPilot added (DataFlash's MOX/MOY/MOZ): with it
        configured, only the samples while disarmed are kept when it is throttle or per-motor based (both zero
        with the motors stopped, AP_Compass::motor_compensation); current-based compensation cannot be undone."""

        if not self.compass.motor_compensation:
            return None
        kind = int(first_value(self.vehicle.parameters, "COMPASS_MOTCT") or 0)
        if kind == 2:
            return (
                "motor compensation by current is active (COMPASS_MOTCT 2): it shifts the field by the current drawn, "
                "which a tlog does not record, so the raw field cannot be recovered; record with COMPASS_MOTCT 0, or "
                "use a DataFlash log (its MAG messages record the compensation)"
            )
        times, armed = self.vehicle.armed
        if not len(times):
            return (
                "motor compensation is active and the tlog has no HEARTBEAT to tell when the vehicle was disarmed "
                "(when the compensation adds nothing); record with COMPASS_MOTCT 0, or use a DataFlash log"
            )
        # Disarmed when the HEARTBEATs on both sides say so: arming between two of them (1 Hz) is seen late.
        after = np.searchsorted(times, self.receipt, side="right")
        disarmed = ~armed[np.clip(after - 1, 0, len(times) - 1)] & ~armed[np.clip(after, 0, len(times) - 1)]
        if not np.any(disarmed):
            return (
                "motor compensation is active and the vehicle was armed for every sample: the compensation added "
                "cannot be undone from a tlog; record disarmed, or use a DataFlash log"
            )
        if not np.all(disarmed):
            notes.append(
                f"motor compensation is active: the {int(np.count_nonzero(~disarmed))} samples while armed are dropped "
                "(the compensation is zero with the motors stopped)"
            )
            self.records, self.time, self.mag = self.records[disarmed], self.time[disarmed], self.mag[disarmed]
            self.receipt = self.receipt[disarmed]
        else:
            notes.append("motor compensation is configured and adds nothing here: the vehicle was disarmed throughout")
        return None

    def read(self) -> LogSamples:

        samples = self.mag.copy()  # PX4: gauss as sent; ArduPilot: mG, calibrated
        notes = tuple(self.notes)
        keep = np.ones(len(samples), dtype=bool)
        if self.compass is not None:
            # Each sample undone with the parameters in effect when it was measured: its time is on the ground
            # station's clock (module docstring), as PARAM_VALUE's receipt times are, within the link's latency.
            undone = undo_records(samples, self.time, parameters=self.vehicle.parameters, compass=self.compass)
            samples, keep, notes = undone.samples, ~undone.damaged, (*notes, *undone.notes)
        finite = np.all(np.isfinite(samples), axis=1) & keep
        if self.every > 1:
            notes += (
                f"one {self.name} message in every {self.every} kept while the log was read ({len(samples)} kept): "
                f"the log holds more than {_KEPT} of them, so a regular stride over the whole log",
            )
        return LogSamples(
            magnetometer=self.magnetometer,
            samples=samples[finite],
            time_s=self.time[finite],
            columns=("xmag", "ymag", "zmag"),
            notes=notes,
            every=self.every,
        )

    def motion(self, position: Position | None) -> Motion:

        read = self.read()
        records = self.records
        if self.px4:
            gyro = np.column_stack([records[f"{a}gyro"] for a in "xyz"]).astype(np.float64)
            accel = np.column_stack([records[f"{a}acc"] for a in "xyz"]).astype(np.float64)
            mounting, mounting_note = None, "PX4 sends HIGHRES_IMU's field already rotated into the body frame"
        else:
            gyro = np.column_stack([records[f"{a}gyro"] for a in "xyz"]).astype(np.float64) / 1000  # mrad/s
            accel = np.column_stack([records[f"{a}acc"] for a in "xyz"]).astype(np.float64) * _GRAVITY_MSS / 1000
            slot = self.magnetometer.slot
            mounting, mounting_note = compass_mounting(self.vehicle.parameters, slot if slot is not None else 0)
        attitude_records, attitude_time = self.vehicle.records("ATTITUDE")
        attitude = None
        if len(attitude_records):
            angles = [np.degrees(attitude_records[a].astype(np.float64)) for a in ("roll", "pitch", "yaw")]
            finite = np.all(np.isfinite(angles), axis=0)
            quaternions = np.full((len(attitude_records), 4), np.nan)
            if np.any(finite):
                quaternions[finite] = euler_quaternions(*(a[finite] for a in angles))
            attitude = Stream("ATTITUDE Roll/Pitch/Yaw", attitude_time, quaternions, "body (FRD)")
            if not self.px4:  # ArduPilot sends AP_AHRS's angles, as ATT logs them: the vehicle body's, trimmed
                attitude = untrimmed(attitude, self.vehicle.parameters)
        imu = f"{self.name} {'IMU' if self.px4 else 'IMU ' + str(self.slot)}"
        # ArduPilot sends zeros for an IMU the board does not have (send_scaled_imu): no stream, not a still one.
        absent = not np.any(accel) and not np.any(gyro)
        return align(
            self.sensor,
            self.unit,
            read.time_s,
            read.samples,
            magnetometer_frame="body",
            attitude=attitude,
            gyro=None if absent else Stream(f"{imu} xgyro/ygyro/zgyro", self.time, gyro, "body (FRD)"),
            accel=None if absent else Stream(f"{imu} xacc/yacc/zacc", self.time, accel, "body (FRD)"),
            mounting=mounting,
            mounting_note=mounting_note,
            position=position,
            start_utc_s=float(read.time_s[0]) if len(read.time_s) else float("nan"),
            notes=(
                f"magnetometer: {self.name} is sent in the body frame (FRD), after the board or COMPASS_ORIENT "
                f"rotation; mounting: {mounting_note}; "
                + (
                    f"{self.name}'s gyro and accel are all zero (no such IMU on the board): left out"
                    if absent
                    else "gyro and accel from the same message (the same clock)"
                ),
            ),
        )


def _position(vehicle: _Vehicle) -> Position | None:
    """The median of GPS_RAW_INT's 3-D fixes (fix_type >= 3), else of GLOBAL_POSITION_INT's non-zero positions;
    the time of the first, on the tlog's clock (UTC)."""
    records, _ = vehicle.records("GPS_RAW_INT")
    frames = vehicle.log.frames("GPS_RAW_INT", vehicle.source)
    if len(records):
        fixed = records["fix_type"] >= 3
        records, frames = records[fixed], frames[fixed]
    if not len(records):
        frames = vehicle.log.frames("GLOBAL_POSITION_INT", vehicle.source)
        records = vehicle.log.messages("GLOBAL_POSITION_INT", frames)
    if not len(records):
        return None
    return median_position(
        records["lat"].astype(np.float64) / 1e7,
        records["lon"].astype(np.float64) / 1e7,
        records["alt"].astype(np.float64) / 1000,
        vehicle.log.receipt_s[frames],
    )
