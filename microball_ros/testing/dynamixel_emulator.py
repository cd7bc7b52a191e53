"""A Dynamixel X-series servo on a pseudo-terminal, speaking Protocol 2.0 (for tests).

Written from the protocol's published packet format (ROBOTIS e-Manual, "Protocol 2.0"), not
from dynamixel-sdk's packet code, so that a test of code using the SDK checks it against an
independent implementation:

    instruction  FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM... | CRC_L CRC_H
    status       FF FF FD 00 | ID | LEN_L LEN_H | 55   | ERR | PARAM... | CRC_L CRC_H

LEN counts the instruction (and error) byte, the parameters and the CRC, after byte stuffing
(FF FF FD in the body is sent as FF FF FD FD); the CRC-16 (polynomial 0x8005, initial value 0,
no reflection) covers everything from the header to the last parameter, stuffing included.
The error byte's bit 7 is the hardware alert, bits 0-6 an error number.

The emulator answers PING, READ and WRITE for one ID and keeps an X-series control table
(model number of an XM430-W350, Velocity Limit as given). Like the real servo it refuses
EEPROM writes (address < 64, e.g. Operating Mode) while torque is on with an Access Error,
refuses a Goal Velocity beyond the Velocity Limit with a Data Limit Error, and lets Present
Velocity follow Goal Velocity while torque is on. Every write is recorded in order with a
monotonic timestamp. ``inject_hardware_error`` sets Hardware Error Status, turns torque off
and raises the alert bit in every later status packet, as the
real servo does; ``silent`` makes it ignore every packet.

    with DynamixelEmulator() as servo:
        run_driver(port=servo.port)        # the slave side of the pty, a tty name
        assert servo.writes_to(64)[-1].value == 0
"""

from dataclasses import dataclass
import os
import select
import threading
import time
import tty

HEADER = b'\xff\xff\xfd\x00'
STATUS = 0x55
PING, READ, WRITE = 0x01, 0x02, 0x03
BROADCAST_ID = 0xFE

# Error numbers of the status packet (bits 0-6) and the alert bit.
RESULT_FAIL, INSTRUCTION_ERROR, CRC_ERROR = 0x01, 0x02, 0x03
DATA_RANGE_ERROR, DATA_LENGTH_ERROR, DATA_LIMIT_ERROR, ACCESS_ERROR = 0x04, 0x05, 0x06, 0x07
ALERT = 0x80

# X-series control table (XM430-W350 e-Manual): address, size.
MODEL_NUMBER = (0, 2)
FIRMWARE_VERSION = (6, 1)
ID = (7, 1)
BAUD_RATE = (8, 1)
OPERATING_MODE = (11, 1)
VELOCITY_LIMIT = (44, 4)
TORQUE_ENABLE = (64, 1)
STATUS_RETURN_LEVEL = (68, 1)
HARDWARE_ERROR_STATUS = (70, 1)
GOAL_VELOCITY = (104, 4)
PRESENT_VELOCITY = (128, 4)
TABLE_SIZE = 147
EEPROM_END = 64                     # addresses below are locked while torque is on
READ_ONLY = set(range(0, 7)) | {69, 70} | set(range(120, TABLE_SIZE))
SIGNED = {GOAL_VELOCITY[0], PRESENT_VELOCITY[0]}

XM430_W350 = 1020
OVERHEATING = 0x04                  # a Hardware Error Status bit


def crc16(data, crc=0):
    """Return the Protocol 2.0 CRC-16 of data: polynomial 0x8005, initial 0, MSB first."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def stuff(body):
    """Return body with 0xFD inserted after every FF FF FD (the e-Manual's byte stuffing)."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if out[-3:] == b'\xff\xff\xfd':
            out.append(0xFD)
    return bytes(out)


def unstuff(body):
    """Invert stuff: drop the 0xFD that follows every FF FF FD."""
    out = bytearray()
    index = 0
    while index < len(body):
        out.append(body[index])
        if out[-3:] == b'\xff\xff\xfd' and body[index + 1:index + 2] == b'\xfd':
            index += 1
        index += 1
    return bytes(out)


def packet(servo_id, instruction, params=b''):
    """Return a whole packet (header, ID, length, stuffed body, CRC) for instruction."""
    body = stuff(bytes([instruction]) + bytes(params))
    head = HEADER + bytes([servo_id]) + (len(body) + 2).to_bytes(2, 'little')
    crc = crc16(head + body)
    return head + body + crc.to_bytes(2, 'little')


def status_packet(servo_id, error, params=b''):
    """Return a status packet (instruction 0x55) with the error byte and parameters."""
    return packet(servo_id, STATUS, bytes([error]) + bytes(params))


def parse(buffer):
    """Split one packet off the front of buffer.

    Returns (packet, rest). packet is (id, instruction, params) with stuffing removed; 'bad'
    for bytes to skip (a length too short to be a packet, or a CRC that does not match: a
    real servo drops such a packet); None while more bytes are needed. Bytes before a header
    are dropped.
    """
    start = buffer.find(HEADER)
    if start < 0:
        return None, buffer[max(0, len(buffer) - 3):]
    buffer = buffer[start:]
    if len(buffer) < 7:
        return None, buffer
    length = int.from_bytes(buffer[5:7], 'little')
    if length < 3:
        return 'bad', buffer[1:]
    end = 7 + length
    if len(buffer) < end:
        return None, buffer
    whole, rest = buffer[:end], buffer[end:]
    if crc16(whole[:-2]) != int.from_bytes(whole[-2:], 'little'):
        return 'bad', rest
    body = unstuff(whole[7:-2])
    return (whole[4], body[0], body[1:]), rest


@dataclass(frozen=True)
class Write:
    """One WRITE instruction the servo received: when, where, what, and whether it took."""

    time: float
    address: int
    data: bytes
    accepted: bool
    error: int

    @property
    def value(self):
        """Return the written data as an integer (4-byte items signed, like the servo)."""
        return int.from_bytes(self.data, 'little', signed=len(self.data) == 4)


class DynamixelEmulator:
    """One Protocol 2.0 X-series servo behind a pseudo-terminal; ``port`` is its tty name."""

    def __init__(self, servo_id=1, model_number=XM430_W350, firmware=45, velocity_limit=1023):
        self.servo_id = servo_id
        self.table = bytearray(TABLE_SIZE)
        self._set(MODEL_NUMBER, model_number)
        self._set(FIRMWARE_VERSION, firmware)
        self._set(ID, servo_id)
        self._set(BAUD_RATE, 1)                  # 57600 bps
        self._set(OPERATING_MODE, 3)             # position control, the factory default
        self._set(VELOCITY_LIMIT, velocity_limit)
        self._set(STATUS_RETURN_LEVEL, 2)        # answer every instruction
        self.writes = []
        self.silent = False
        self.present_velocity_override = None
        self.packets_received = 0
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name='dynamixel-emulator',
                                        daemon=True)
        self._thread.start()

    # -- the control table --------------------------------------------------------------
    def _set(self, item, value):
        address, size = item
        self.table[address:address + size] = int(value).to_bytes(
            size, 'little', signed=address in SIGNED)

    def set(self, item, value):
        """Set a control-table item directly, as if the servo had been left that way."""
        with self._lock:
            self._set(item, value)
            self._follow()

    def get(self, item):
        """Return a control-table item, e.g. ``get(GOAL_VELOCITY)``."""
        address, size = item
        with self._lock:
            return int.from_bytes(self.table[address:address + size], 'little',
                                  signed=address in SIGNED)

    def writes_to(self, address):
        """Return the recorded writes that started at address, in order."""
        with self._lock:
            return [w for w in self.writes if w.address == address]

    def wait_for(self, condition, timeout=10.0):
        """Wait until condition(self) holds, rechecked after every packet; False on timeout."""
        deadline = time.monotonic() + timeout
        while not condition(self):
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            with self._changed:
                self._changed.wait(min(left, 0.1))
        return True

    def inject_hardware_error(self, bits=OVERHEATING):
        """Raise a hardware error: set Hardware Error Status, torque off, alert in every reply."""
        with self._lock:
            self._set(HARDWARE_ERROR_STATUS, bits)
            self._set(TORQUE_ENABLE, 0)
            self._follow()

    def _follow(self):
        torque = self.table[TORQUE_ENABLE[0]]
        goal = int.from_bytes(self.table[104:108], 'little', signed=True)
        if self.present_velocity_override is not None and torque:
            goal = self.present_velocity_override
        self._set(PRESENT_VELOCITY, goal if torque else 0)

    def set_present_velocity(self, value):
        """Pin Present Velocity to value while torque is on (None: follow Goal Velocity)."""
        with self._lock:
            self.present_velocity_override = value
            self._follow()

    # -- the protocol -------------------------------------------------------------------
    def _error(self, number):
        alert = ALERT if self.table[HARDWARE_ERROR_STATUS[0]] else 0
        return alert | number

    def _read(self, params):
        if len(params) != 4:
            return self._error(DATA_LENGTH_ERROR), b''
        address = int.from_bytes(params[0:2], 'little')
        length = int.from_bytes(params[2:4], 'little')
        if address + length > TABLE_SIZE:
            return self._error(ACCESS_ERROR), b''
        self._follow()
        return self._error(0), bytes(self.table[address:address + length])

    def _write(self, params):
        if len(params) < 3:
            return self._error(DATA_LENGTH_ERROR)
        address = int.from_bytes(params[0:2], 'little')
        data = bytes(params[2:])
        error = self._check_write(address, data)
        self.writes.append(Write(time.monotonic(), address, data, error == 0, error))
        if error == 0:
            self.table[address:address + len(data)] = data
            self._follow()
        return self._error(error)

    def _check_write(self, address, data):
        touched = range(address, address + len(data))
        if address + len(data) > TABLE_SIZE or any(a in READ_ONLY for a in touched):
            return ACCESS_ERROR
        if address < EEPROM_END and self.table[TORQUE_ENABLE[0]]:
            return ACCESS_ERROR                      # ROM lock while torque is on
        if address == OPERATING_MODE[0] and data[0] not in (0, 1, 3, 4, 5, 16):
            return DATA_RANGE_ERROR
        if address == TORQUE_ENABLE[0] and data[0] > 1:
            return DATA_RANGE_ERROR
        if address == TORQUE_ENABLE[0] and data[0] and self.table[HARDWARE_ERROR_STATUS[0]]:
            return RESULT_FAIL                       # torque stays off until a reboot
        if address == GOAL_VELOCITY[0]:
            if len(data) != 4:
                return DATA_LENGTH_ERROR
            limit = int.from_bytes(self.table[44:48], 'little')
            if abs(int.from_bytes(data, 'little', signed=True)) > limit:
                return DATA_LIMIT_ERROR
        return 0

    def handle(self, servo_id, instruction, params):
        """Execute one instruction packet; return the status packet to send, or None."""
        with self._changed:
            self.packets_received += 1
            try:
                if self.silent or servo_id not in (self.servo_id, BROADCAST_ID):
                    return None
                if instruction == PING:
                    info = self.table[0:2] + self.table[6:7]
                    return status_packet(self.servo_id, self._error(0), info)
                if servo_id == BROADCAST_ID:
                    return None                  # no status for broadcast READ / WRITE
                if instruction == READ:
                    error, data = self._read(params)
                    return status_packet(self.servo_id, error, data)
                if instruction == WRITE:
                    return status_packet(self.servo_id, self._write(params))
                return status_packet(self.servo_id, self._error(INSTRUCTION_ERROR))
            finally:
                self._changed.notify_all()

    def _serve(self):
        buffer = b''
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.05)
            if not ready:
                continue
            try:
                buffer += os.read(self._master, 4096)
            except OSError:
                return
            while True:
                parsed, buffer = parse(buffer)
                if parsed is None:
                    break
                if parsed == 'bad':
                    continue
                reply = self.handle(*parsed)
                if reply is not None:
                    os.write(self._master, reply)

    def close(self):
        """Stop answering and release the pseudo-terminal."""
        self._stop.set()
        self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
