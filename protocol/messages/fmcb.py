"""Messages of the finger motor control board (fmcb) application.

Ids and layouts are the original hand's (reference: sandia-hand facts §2); the 148-byte
status keeps its explicit padding.  New: a homing-offset message.
"""

from __future__ import annotations

from enum import IntEnum

import construct as c

from protocol.catalogue import Message
from protocol.enum_field import EnumField
from protocol.messages.fields import EMPTY, IMU6, counted_bytes


class ControlMode(IntEnum):
    """Control mode of ``fmcb.control``; it selects the layout of the arguments."""

    IDLE = 0
    MOTOR = 1
    JOINT = 2
    JOINT_FIXED = 3
    JOINT_EFFORT = 4
    RELATIVE = 5


#: Largest byte count the tunnel carries in either direction.
TUNNEL_MAX = 512

_JOINT_EFFORT = c.Struct(
    "target" / c.Array(3, c.Float32l) * "[rad] joint targets J1, J2, J3 (relative: deltas)",
    "max_effort" / c.Array(3, c.Int8ul) * "[1/255 of full PWM] per-joint effort cap",
)

CONTROL = c.Struct(
    "mode" / EnumField(c.Int8ul, ControlMode) * "[-] control mode (joint fixed: fixed-point "
    "targets; relative: deltas with effort caps)",
    "args"
    / c.Switch(
        c.this.mode,
        {
            ControlMode.IDLE: c.Struct(),
            ControlMode.MOTOR: c.Struct(
                "hall_target" / c.Array(3, c.Int16sl) * "[hall counts] motor targets"),
            ControlMode.JOINT: c.Struct(
                "target" / c.Array(3, c.Float32l) * "[rad] joint targets J1, J2, J3"),
            ControlMode.JOINT_FIXED: c.Struct(
                "target" / c.Array(3, c.Int16sl) * "[1e-4 rad] joint targets"),
            ControlMode.JOINT_EFFORT: _JOINT_EFFORT,
            ControlMode.RELATIVE: _JOINT_EFFORT,
        },
        c.Error,
    )
    * "[-] mode-dependent arguments",
)

STATUS = c.Struct(
    "pp_time" / c.Int32ul * "[µs] proximal phalange timestamp",
    "dp_time" / c.Int32ul * "[µs] distal phalange timestamp",
    "fmcb_time" / c.Int32ul * "[µs] fmcb timestamp (monotonic in this firmware)",
    "pp_tactile" / c.Array(6, c.Int16ul) * "[ADC counts] proximal taxels",
    "dp_tactile" / c.Array(12, c.Int16ul) * "[ADC counts] distal taxels",
    "pp_imu" / c.Array(6, c.Int16sl) * "[mg, counts] proximal accel xyz, mag xyz",
    "dp_imu" / c.Array(6, c.Int16sl) * "[mg, counts] distal accel xyz, mag xyz",
    "fmcb_imu" / c.Array(6, c.Int16sl) * "[mg, counts] motor module accel xyz, mag xyz",
    "pp_temp" / c.Array(4, c.Int16ul) * "[ADC counts] proximal thermistors",
    "dp_temp" / c.Array(4, c.Int16ul) * "[ADC counts] distal thermistors",
    "fmcb_temp" / c.Array(3, c.Int16ul) * "[ADC counts] motor temperatures "
    "(protocol.sensor_counts.temperature_c)",
    "voltage" / c.Int16ul * "[ADC counts] logic supply voltage "
    "(protocol.sensor_counts.supply_volts)",
    "pb_current" / c.Int16ul * "[ADC counts] phalange bus current "
    "(protocol.sensor_counts.pb_current_amps); 0xFFFF = breaker tripped",
    c.Padding(2) * "explicit padding at offset 110 (C struct alignment)",
    "pp_strain" / c.Int32sl * "[counts] proximal strain gauge (24-bit, sign-extended)",
    "hall_tgt" / c.Array(3, c.Int32sl) * "[hall counts] motor targets",
    "hall_pos" / c.Array(3, c.Int32sl) * "[hall counts] motor positions",
    "effort" / c.Array(3, c.Int16sl) * "[1/255 of full PWM] signed motor effort",
    c.Padding(2) * "explicit padding at the end (C struct alignment)",
)

HALL_COUNTS = c.Struct(
    "counts" / c.Array(3, c.Int32sl) * "[hall counts] motor positions",
    "velocity" / c.Array(3, c.Int32sl) * "[hall counts/s] motor velocities",
)

MESSAGES: list[Message] = [
    Message("fmcb.imu", "fmcb", 0x10, EMPTY, IMU6, "Motor-module accelerometer and magnetometer."),
    Message(
        "fmcb.halls",
        "fmcb",
        0x12,
        EMPTY,
        c.Struct("bits" / c.Array(3, c.Int8ul) * "[-] raw hall bits per motor (3 bits each)"),
        "Raw hall sensor states.",
    ),
    Message(
        "fmcb.motor_raw",
        "fmcb",
        0x13,
        c.Struct(
            "enable" / c.Int8ul * "[-] bit i enables motor i",
            "direction" / c.Int8ul * "[-] bit i reverses motor i",
            "brake" / c.Int8ul * "[-] bit i brakes motor i",
            "duty" / c.Array(3, c.Int8ul) * "[1/255 of full PWM] duty per motor",
        ),
        c.Struct("counts" / c.Array(3, c.Int32sl) * "[hall counts] raw motor positions"),
        "Legacy open-loop motor command.",
    ),
    Message(
        "fmcb.hall_counts",
        "fmcb",
        0x14,
        c.Struct("raw" / c.Int8ul * "[-] 0 = apply homing offsets, 1 = raw counts"),
        HALL_COUNTS,
        "Motor positions and velocities.",
    ),
    Message(
        "fmcb.param_count",
        "fmcb",
        0x16,
        EMPTY,
        c.Struct("count" / c.Int16ul * "[-] number of parameters"),
        "How many parameters the board has.",
    ),
    Message(
        "fmcb.param_name",
        "fmcb",
        0x17,
        c.Struct("index" / c.Int16ul * "[-] parameter index"),
        c.Struct("name" / c.PascalString(c.Int8ul, "ascii") * "[-] parameter name"),
        "Name of a parameter.",
    ),
    Message(
        "fmcb.param_get",
        "fmcb",
        0x18,
        c.Struct("index" / c.Int16ul * "[-] parameter index"),
        c.Struct("value" / c.Bytes(4) * "[-] value bits (f32 or u32 LE, per parameter)"),
        "Value of a parameter.",
    ),
    Message(
        "fmcb.param_set",
        "fmcb",
        0x19,
        c.Struct(
            "index" / c.Int16ul * "[-] parameter index",
            "value" / c.Bytes(4) * "[-] value bits (f32 or u32 LE, per parameter)",
        ),
        EMPTY,
        "Set a parameter in RAM (commit to keep it).",
    ),
    Message("fmcb.param_commit", "fmcb", 0x1A, EMPTY, EMPTY, "Write parameters to flash."),
    Message("fmcb.param_reload", "fmcb", 0x1B, EMPTY, EMPTY, "Reload parameters from flash."),
    Message("fmcb.param_defaults", "fmcb", 0x1C, EMPTY, EMPTY, "Restore default parameters."),
    Message("fmcb.control", "fmcb", 0x1D, CONTROL, None, "Set control mode and targets."),
    Message(
        "fmcb.phalange_power",
        "fmcb",
        0x1E,
        c.Struct("on" / c.Int8ul * "[-] bit0: phalange bus power"),
        EMPTY,
        "Switch the tendon (phalange) bus power.",
    ),
    Message(
        "fmcb.tunnel",
        "fmcb",
        0x1F,
        c.Struct(
            "length" / c.Rebuild(c.Int16ul, c.len_(c.this.data)) * "[bytes] bytes to send",
            "max_ms" / c.Int16ul * "[ms] how long to listen on the phalange bus",
            c.Check(c.this.length <= TUNNEL_MAX),
            "data" / c.Bytes(c.this.length) * "[-] raw bytes for the phalange bus",
        ),
        counted_bytes(TUNNEL_MAX, "[-] raw bytes heard on the phalange bus"),
        "Send raw bytes on the tendon bus and return what was heard.",
    ),
    Message(
        "fmcb.autopoll",
        "fmcb",
        0x20,
        c.Struct("on" / c.Int8ul * "[-] 1 = poll f2 and f3 every 10 ms"),
        EMPTY,
        "Phalange autopoll on/off.",
    ),
    Message("fmcb.status", "fmcb", 0x21, EMPTY, STATUS, "The 148-byte status snapshot."),
    Message(
        "fmcb.temperatures",
        "fmcb",
        0x22,
        EMPTY,
        c.Struct("temp" / c.Array(3, c.Int16ul) * "[ADC counts] motor temperatures "
                 "(protocol.sensor_counts.temperature_c)"),
        "Motor temperatures.",
    ),
    Message(
        "fmcb.effort_cap",
        "fmcb",
        0x23,
        c.Struct("cap" / c.Int8ul * "[1/255 of full PWM] hand-wide effort cap"),
        None,
        "Effort cap from the palm's current governor.",
    ),
    Message(
        "fmcb.set_home",
        "fmcb",
        0x24,
        c.Struct("offset" / c.Array(3, c.Int32sl) * "[hall counts] new zero of each motor"),
        EMPTY,
        "Set the homing offsets of the hall counts.",
        original=False,
    ),
]
