"""CANopen CiA 402 drives in profile velocity mode: objects, the drive state machine, units and frame kinds.

Pure code, no I/O; shared by the driver (:mod:`runtime.drivers.cia402`, master side through ``canopen``'s
``BaseNode402``) and the SITL drive emulators (:mod:`sitl.devices.cia402`, on ``canopen``'s ``LocalNode``).
Sources: CiA 301 (NMT commands 0x01/0x02/0x80/0x81/0x82, heartbeat COB-ID 0x700+id with states 0/4/5/127,
EMCY 0x80+id with code, error register and 5 vendor bytes, PDO COB-IDs 0x200+id / 0x180+id, mapping entries
``index<<16 | sub<<8 | bits``, heartbeat consumer 0x1016 = node id in bits 16-23 and ms in bits 0-15) and
CiA 402 (controlword commands Shutdown 0x06, Switch on 0x07, Enable operation 0x0F, Quick stop 0x02, Disable
voltage 0x00, Fault reset = rising edge of bit 7; statusword masks as ``canopen.profiles.p402.State402``;
modes of operation 0x6060/0x6061 with 3 = profile velocity; supported modes 0x6502 bit 2 = pv).

* :func:`object_dictionary`: the objects a drive of this base has (a vendor EDS may stand in for it).
* :class:`Drive402`: the drive's state machine (controlword in, statusword out), as a real drive runs it.
* :class:`WheelUnits`: m/s and metres <-> the drive's velocity unit and encoder counts.
* :func:`classify`: what a frame on the bus is (NMT, SYNC, EMCY, PDO, SDO, heartbeat) and whether its length
  is one that kind can have; the driver and the emulator count frames with it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from canopen import objectdictionary as od
from canopen.profiles.p402 import State402

from runtime.errors import InputError

# ----------------------------------------------------------------------------- CiA 301
NMT_START, NMT_STOP, NMT_PRE_OPERATIONAL, NMT_RESET_NODE, NMT_RESET_COMMUNICATION = 0x01, 0x02, 0x80, 0x81, 0x82
HB_BOOTUP, HB_STOPPED, HB_OPERATIONAL, HB_PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F
NMT_NAMES = {HB_BOOTUP: "boot-up", HB_STOPPED: "stopped", HB_OPERATIONAL: "operational",
             HB_PRE_OPERATIONAL: "pre-operational"}
COB_NMT, COB_SYNC = 0x000, 0x080
COB_EMCY, COB_TPDO1, COB_RPDO1, COB_TPDO2, COB_RPDO2 = 0x080, 0x180, 0x200, 0x280, 0x300
COB_SDO_TX, COB_SDO_RX, COB_HEARTBEAT = 0x580, 0x600, 0x700
DEVICE_TYPE_402 = 0x00020192          # 0x1000: profile 402 (low word), servo drive (additional information 2)

# EMCY error codes (CiA 301 table 21 and CiA 402) the emulator raises and the driver names
EMCY_NO_ERROR = 0x0000
EMCY_OVERCURRENT = 0x2310             # continuous over current
EMCY_OVERVOLTAGE = 0x3210             # DC link over-voltage
EMCY_OVERTEMPERATURE = 0x4310         # drive temperature
EMCY_ENCODER = 0x7305                 # incremental sensor 1 fault
EMCY_HEARTBEAT = 0x8130               # life guard or heartbeat error
EMCY_FOLLOWING = 0x8611               # following error
ERROR_REGISTER_BITS = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}   # 0x1001: current, voltage, temperature, comm


def error_register(code: int) -> int:
    """0x1001 for an active EMCY ``code``: bit 0 (generic) plus the class bit its first digit names."""
    return 0 if code == EMCY_NO_ERROR else 0x01 | ERROR_REGISTER_BITS.get(code >> 12, 0)


# ----------------------------------------------------------------------------- CiA 402
CW_DISABLE_VOLTAGE, CW_QUICK_STOP, CW_SHUTDOWN = State402.CW_DISABLE_VOLTAGE, State402.CW_QUICK_STOP, State402.CW_SHUTDOWN
CW_SWITCH_ON, CW_ENABLE_OPERATION, CW_FAULT_RESET = State402.CW_SWITCH_ON, State402.CW_OPERATION_ENABLED, 0x0080
CW_HALT = 0x0100
MODE_PROFILE_VELOCITY = 3
SUPPORTED_MODES = 0x0004              # 0x6502: profile velocity only
QUICK_STOP_STAY = 6                   # 0x605A: slow down on the quick stop ramp and stay in QUICK STOP ACTIVE
ABORT_FAULT, ABORT_DISABLE_VOLTAGE, ABORT_QUICK_STOP = 1, 2, 3      # 0x6007 abort connection option codes

NOT_READY, SWITCH_ON_DISABLED, READY, SWITCHED_ON = ("NOT READY TO SWITCH ON", "SWITCH ON DISABLED",
                                                     "READY TO SWITCH ON", "SWITCHED ON")
ENABLED, QUICK_STOP, FAULT_REACTION, FAULT = ("OPERATION ENABLED", "QUICK STOP ACTIVE", "FAULT REACTION ACTIVE",
                                              "FAULT")
# Statusword bits 0-6 of each state (within State402.SW_MASK); bit 4 "voltage enabled" while the power stage has
# voltage, bit 5 "quick stop" is active low, bit 9 "remote" (controlled over the bus).
STATUSWORD = {NOT_READY: 0x0000, SWITCH_ON_DISABLED: 0x0040, READY: 0x0031, SWITCHED_ON: 0x0033, ENABLED: 0x0037,
              QUICK_STOP: 0x0017, FAULT_REACTION: 0x001F, FAULT: 0x0008}
SW_REMOTE, SW_TARGET_REACHED, SW_WARNING = 0x0200, 0x0400, 0x0080


def state_of(statusword: int) -> str:
    """The 402 state a statusword reports (``State402.SW_MASK``), or "UNKNOWN"."""
    for state, (mask, bits) in State402.SW_MASK.items():
        if statusword & mask == bits:
            return state
    return "UNKNOWN"


class Drive402:
    """A drive's CiA 402 state machine.  :meth:`command` takes each controlword as it arrives; the motor may
    turn only in OPERATION ENABLED (it follows the target) and ramps down in QUICK STOP ACTIVE and FAULT
    REACTION ACTIVE.  Transition numbers are CiA 402's."""

    def __init__(self):
        self.state = SWITCH_ON_DISABLED      # 0 and 1 happen on power-up
        self._last_cw = 0

    def command(self, cw: int) -> bool:
        """Apply controlword ``cw``; True if the state changed."""
        before, edge = self.state, bool(cw & CW_FAULT_RESET and not self._last_cw & CW_FAULT_RESET)
        self._last_cw = cw
        s = self.state
        if s == FAULT:
            if edge:
                self.state = SWITCH_ON_DISABLED                      # 15
        elif s == FAULT_REACTION or cw & CW_FAULT_RESET:
            pass                                                     # commands have bit 7 clear
        elif cw & 0x02 == 0:                                         # disable voltage: 7, 9, 10, 12
            if s in (READY, SWITCHED_ON, ENABLED, QUICK_STOP):
                self.state = SWITCH_ON_DISABLED
        elif cw & 0x06 == 0x02:                                      # quick stop: 7, 10, 11
            if s in (READY, SWITCHED_ON):
                self.state = SWITCH_ON_DISABLED
            elif s == ENABLED:
                self.state = QUICK_STOP
        elif cw & 0x07 == 0x06:                                      # shutdown: 2, 6, 8
            if s in (SWITCH_ON_DISABLED, SWITCHED_ON, ENABLED):
                self.state = READY
        elif cw & 0x0F == 0x07:                                      # switch on 3, disable operation 5
            if s in (READY, ENABLED):
                self.state = SWITCHED_ON
        elif cw & 0x0F == 0x0F:                                      # enable operation: 4, 16, (3 + 4)
            if s in (READY, SWITCHED_ON, QUICK_STOP):
                self.state = ENABLED
        return self.state != before

    def fault(self) -> bool:
        """A fault is detected: FAULT REACTION ACTIVE (13) unless already faulted.  True if it was new."""
        if self.state in (FAULT, FAULT_REACTION):
            return False
        self.state = FAULT_REACTION
        return True

    def reaction_done(self) -> None:
        """The fault reaction (stopping the motor) has finished: FAULT (14)."""
        if self.state == FAULT_REACTION:
            self.state = FAULT

    @property
    def enabled(self) -> bool:
        return self.state == ENABLED

    @property
    def stopping(self) -> bool:
        """The motor ramps down on the quick stop deceleration."""
        return self.state in (QUICK_STOP, FAULT_REACTION)

    def statusword(self, target_reached: bool = False) -> int:
        return STATUSWORD[self.state] | SW_REMOTE | (SW_TARGET_REACHED if target_reached else 0)


# ----------------------------------------------------------------------------- object dictionary
def _var(name: str, index: int, sub: int, dtype: int, access: str, default=None) -> od.ODVariable:
    v = od.ODVariable(name, index, sub)
    v.data_type, v.access_type, v.default = dtype, access, default
    return v


def _pdo_records(d: od.ObjectDictionary, com: int, mapping: int, cob: int, node_id: int, first: tuple) -> None:
    """Four PDO communication records (COB-ID, transmission type, inhibit time, event timer, SYNC start) and
    mapping arrays; the first PDO maps ``first`` by default (the predefined connection set)."""
    for n in range(4):
        rec = od.ODRecord(f"PDO {n + 1} communication parameter", com + n)
        for sub, name, dtype, default in ((0, "Highest sub-index supported", od.UNSIGNED8, 6),
                                          (1, "COB-ID", od.UNSIGNED32, (cob + 0x100 * n + node_id) | (0 if n == 0 else 0x80000000)),
                                          (2, "Transmission type", od.UNSIGNED8, 255),
                                          (3, "Inhibit time", od.UNSIGNED16, 0),
                                          (5, "Event timer", od.UNSIGNED16, 0),
                                          (6, "SYNC start value", od.UNSIGNED8, 0)):
            rec.add_member(_var(name, com + n, sub, dtype, "ro" if sub == 0 else "rw", default))
        d.add_object(rec)
        arr = od.ODRecord(f"PDO {n + 1} mapping parameter", mapping + n)
        entries = first if n == 0 else ()
        arr.add_member(_var("Number of mapped objects", mapping + n, 0, od.UNSIGNED8, "rw", len(entries)))
        for sub in range(1, 9):
            arr.add_member(_var(f"Mapped object {sub}", mapping + n, sub, od.UNSIGNED32, "rw",
                                entries[sub - 1] if sub <= len(entries) else 0))
        d.add_object(arr)


def map_entry(index: int, sub: int, bits: int) -> int:
    """A PDO mapping entry: ``index<<16 | sub<<8 | bits``."""
    return index << 16 | sub << 8 | bits


def object_dictionary(node_id: int) -> od.ObjectDictionary:
    """The object dictionary of one drive of this base: CiA 301 communication objects and the CiA 402 objects
    profile velocity mode needs."""
    d = od.ObjectDictionary()
    d.node_id = node_id
    for name, index, dtype, access, default in (
            ("Device type", 0x1000, od.UNSIGNED32, "ro", DEVICE_TYPE_402),
            ("Error register", 0x1001, od.UNSIGNED8, "ro", 0),
            ("Producer heartbeat time", 0x1017, od.UNSIGNED16, "rw", 0),
            ("Abort connection option code", 0x6007, od.INTEGER16, "rw", ABORT_FAULT),
            ("Error code", 0x603F, od.UNSIGNED16, "ro", 0),
            ("Controlword", 0x6040, od.UNSIGNED16, "rw", 0),
            ("Statusword", 0x6041, od.UNSIGNED16, "ro", 0),
            ("Quick stop option code", 0x605A, od.INTEGER16, "rw", QUICK_STOP_STAY),
            ("Modes of operation", 0x6060, od.INTEGER8, "rw", 0),
            ("Modes of operation display", 0x6061, od.INTEGER8, "ro", 0),
            ("Position actual value", 0x6064, od.INTEGER32, "ro", 0),
            ("Velocity actual value", 0x606C, od.INTEGER32, "ro", 0),
            ("Profile acceleration", 0x6083, od.UNSIGNED32, "rw", 10000),
            ("Profile deceleration", 0x6084, od.UNSIGNED32, "rw", 10000),
            ("Quick stop deceleration", 0x6085, od.UNSIGNED32, "rw", 20000),
            ("Target velocity", 0x60FF, od.INTEGER32, "rw", 0),
            ("Supported drive modes", 0x6502, od.UNSIGNED32, "ro", SUPPORTED_MODES)):
        d.add_object(_var(name, index, 0, dtype, access, default))
    consumer = od.ODArray("Consumer heartbeat time", 0x1016)
    consumer.add_member(_var("Number of entries", 0x1016, 0, od.UNSIGNED8, "ro", 1))
    consumer.add_member(_var("Consumer heartbeat time 1", 0x1016, 1, od.UNSIGNED32, "rw", 0))
    d.add_object(consumer)
    identity = od.ODRecord("Identity object", 0x1018)
    for sub, name, default in ((0, "Highest sub-index supported", 4), (1, "Vendor-ID", 0), (2, "Product code", 402),
                               (3, "Revision number", 1), (4, "Serial number", node_id)):
        identity.add_member(_var(name, 0x1018, sub, od.UNSIGNED8 if sub == 0 else od.UNSIGNED32, "ro", default))
    d.add_object(identity)
    _pdo_records(d, 0x1400, 0x1600, COB_RPDO1, node_id, (map_entry(0x6040, 0, 16),))
    _pdo_records(d, 0x1800, 0x1A00, COB_TPDO1, node_id, (map_entry(0x6041, 0, 16),))
    return d


def consumer_entry(producer_id: int, period_s: float) -> int:
    """0x1016 sub-index value: monitor node ``producer_id``'s heartbeat, expecting one within ``period_s``."""
    return (producer_id & 0x7F) << 16 | max(1, min(0xFFFF, round(period_s * 1000)))


# ----------------------------------------------------------------------------- units
@dataclass(frozen=True)
class WheelUnits:
    """Conversions between a wheel's m/s and metres and its drive's units.

    ``counts_per_rev``: encoder increments per motor revolution (position actual 0x6064 counts them);
    ``gear_ratio``: motor revolutions per wheel revolution; ``velocity_unit``: the unit of 0x60FF and 0x606C,
    motor ``rpm`` or encoder ``counts_per_s``; accelerations (0x6083-0x6085) are that unit per second."""
    wheel_radius: float
    counts_per_rev: int
    gear_ratio: float = 1.0
    velocity_unit: Literal["rpm", "counts_per_s"] = "rpm"

    def __post_init__(self):
        for name in ("wheel_radius", "counts_per_rev", "gear_ratio"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"CiA 402 base {name} {v!r}: expected a finite number > 0")
        if self.velocity_unit not in ("rpm", "counts_per_s"):
            raise InputError(f"CiA 402 base velocity_unit {self.velocity_unit!r}: expected rpm or counts_per_s")

    @property
    def counts_per_rad(self) -> float:
        """Position actual counts per radian the wheel turns."""
        return self.counts_per_rev * self.gear_ratio / (2 * math.pi)

    @property
    def unit_per_rad_s(self) -> float:
        """Drive velocity units per rad/s of the wheel."""
        if self.velocity_unit == "rpm":
            return 60.0 * self.gear_ratio / (2 * math.pi)
        return self.counts_per_rad

    @property
    def counts_per_m(self) -> float:
        return self.counts_per_rad / self.wheel_radius

    @property
    def unit_per_mps(self) -> float:
        """Drive velocity units per m/s at the wheel rim."""
        return self.unit_per_rad_s / self.wheel_radius

    def velocity(self, mps: float) -> int:
        """m/s at the rim -> the drive's velocity unit (rounded)."""
        return round(mps * self.unit_per_mps)

    def mps(self, value: float) -> float:
        """The drive's velocity unit -> m/s at the rim."""
        return value / self.unit_per_mps

    def metres(self, counts: float) -> float:
        return counts / self.counts_per_m


def delta32(new: int, old: int) -> int:
    """Signed difference of two INTEGER32 positions, across a wrap either way."""
    return (new - old + 0x80000000) % 0x100000000 - 0x80000000


# ----------------------------------------------------------------------------- frames
# (function code & 0x780) -> (kind, allowed data lengths); node ids 1..127 except NMT and SYNC
_KINDS = {COB_EMCY: ("emcy", (8,)), COB_TPDO1: ("tpdo", range(0, 9)), COB_RPDO1: ("rpdo", range(0, 9)),
          COB_TPDO2: ("tpdo", range(0, 9)), COB_RPDO2: ("rpdo", range(0, 9)), 0x380: ("tpdo", range(0, 9)),
          0x400: ("rpdo", range(0, 9)), 0x480: ("tpdo", range(0, 9)), 0x500: ("rpdo", range(0, 9)),
          COB_SDO_TX: ("sdo_tx", (8,)), COB_SDO_RX: ("sdo_rx", (8,)), COB_HEARTBEAT: ("heartbeat", (1,))}


def classify(can_id: int, data: bytes, extended: bool = False) -> tuple[str, int] | None:
    """``(kind, node id)`` of a CANopen frame of the predefined connection set, or None for a frame no CiA 301
    service sends (an extended id, an unknown function code, node id 0 where one is needed, or a data
    length that kind never has).  NMT is ``("nmt", addressed node)``, SYNC ``("sync", 0)``."""
    if extended or not 0 <= can_id <= 0x7FF or len(data) > 8:
        return None
    if can_id == COB_NMT:
        return ("nmt", data[1]) if len(data) == 2 and data[1] <= 127 else None
    if can_id == COB_SYNC:
        return ("sync", 0) if len(data) <= 1 else None
    node = can_id & 0x7F
    kind = _KINDS.get(can_id & 0x780)
    if kind is None or node == 0 or len(data) not in kind[1]:
        return None
    if kind[0] == "heartbeat" and data[0] & 0x7F not in NMT_NAMES:
        return None
    return kind[0], node
