"""Dynamixel X-series servo in velocity control over Protocol 2.0, through dynamixel-sdk.

The servo_commander's ``driver:=dynamixel``. Control table items used (X-series e-Manual):
Operating Mode (11, 1 byte; 1 = velocity control, writable only with torque off), Velocity
Limit (44, 4), Torque Enable (64, 1), Hardware Error Status (70, 1), Goal Velocity (104, 4,
signed, 0.229 rev/min), Present Velocity (128, 4, signed, 0.229 rev/min).

Start: ping, Torque Enable 0, Operating Mode 1, read Velocity Limit; the first ``drive`` sets
Torque Enable 1, then Goal Velocity = round(60 f / gear_ratio / 0.229) for crank frequency f.
Stop (and close, and any error): Goal Velocity 0, then Torque Enable 0. A status packet with
the hardware alert bit (bit 7 of its error byte) is logged with the Hardware Error Status and
stops the motor. A port that cannot be opened, or a servo that does not answer, is an
InputError with one line in the user's terms.
"""

import math
import os

from microball_ros.core.errors import InputError
from microball_ros.core.servo import ServoDriver

FIRMWARE_VERSION = 6
OPERATING_MODE = 11
VELOCITY_LIMIT = 44
TORQUE_ENABLE = 64
HARDWARE_ERROR_STATUS = 70
GOAL_VELOCITY = 104
PRESENT_VELOCITY = 128

VELOCITY_CONTROL = 1
VELOCITY_UNIT_RPM = 0.229          # rev/min per unit of Goal / Present Velocity
ALERT = 0x80
RETRIES = 3                        # attempts per transaction before the servo counts as silent

ERROR_NAMES = {1: 'result fail', 2: 'instruction error', 3: 'CRC error',
               4: 'data range error', 5: 'data length error', 6: 'data limit error',
               7: 'access error'}
HARDWARE_ERRORS = {0x01: 'input voltage', 0x04: 'overheating', 0x08: 'motor encoder',
                   0x10: 'electrical shock', 0x20: 'overload'}
NAMES = {OPERATING_MODE: 'Operating Mode', VELOCITY_LIMIT: 'Velocity Limit',
         TORQUE_ENABLE: 'Torque Enable', HARDWARE_ERROR_STATUS: 'Hardware Error Status',
         GOAL_VELOCITY: 'Goal Velocity', PRESENT_VELOCITY: 'Present Velocity'}


def goal_velocity_units(frequency, gear_ratio):
    """Return Goal Velocity (units of 0.229 rev/min) for crank frequency (Hz).

    gear_ratio is crank turns per motor turn.
    """
    return round(60.0 * frequency / gear_ratio / VELOCITY_UNIT_RPM)


def crank_angular_velocity(units, gear_ratio):
    """Return the crank angular velocity (rad/s) of a motor velocity in 0.229 rev/min units."""
    return units * VELOCITY_UNIT_RPM * gear_ratio * 2.0 * math.pi / 60.0


def signed32(value):
    """Return the 4-byte control table value (unsigned as read) as a signed integer."""
    return value - (1 << 32) if value & 0x80000000 else value


def hardware_error_text(status):
    """Return the Hardware Error Status bits in words, e.g. 'overheating'."""
    names = [name for bit, name in HARDWARE_ERRORS.items() if status & bit]
    return ', '.join(names) or f'status 0x{status:02X}'


class DynamixelDriver(ServoDriver):
    """One Dynamixel X-series servo in velocity control turning the crank."""

    def __init__(self, values, log):
        self.port_name = values['port']
        self.baudrate = int(values['baudrate'])
        self.servo_id = int(values['servo_id'])
        self.gear_ratio = float(values['gear_ratio'])
        self.log = log
        self.fault = None
        self.velocity_limit = None
        self._torque = False
        self._port = None
        self._packets = None
        self._handling_alert = False
        self._answered = False        # the servo answered a ping: stopping it makes sense

    @property
    def max_frequency(self):
        """Return the crank frequency (Hz) at the servo's Velocity Limit (None before open)."""
        if self.velocity_limit is None:
            return None
        return self.velocity_limit * VELOCITY_UNIT_RPM * self.gear_ratio / 60.0

    def _where(self):
        return f'Dynamixel ID {self.servo_id} on {self.port_name} at {self.baudrate} baud'

    def open(self):
        """Open the port, find the servo, and put it in velocity control with torque off."""
        try:
            import dynamixel_sdk
        except ImportError as error:
            raise InputError('driver dynamixel needs the dynamixel-sdk package '
                             '(pip install dynamixel-sdk)') from error
        if not self.port_name:
            raise InputError('driver dynamixel needs the port parameter (e.g. /dev/ttyUSB0)')
        if not os.path.exists(self.port_name):
            raise InputError(f'servo port {self.port_name} does not exist '
                             '(is the servo adapter plugged in?)')
        self._sdk = dynamixel_sdk
        port = dynamixel_sdk.PortHandler(self.port_name)
        try:
            opened = port.openPort() and port.setBaudRate(self.baudrate)
        except Exception as error:  # pyserial raises SerialException (an OSError) or ValueError
            raise InputError(f'cannot open servo port {self.port_name}: '
                             f'{_first_line(error)}') from error
        if not opened:
            port.closePort()
            raise InputError(f'cannot open servo port {self.port_name} at {self.baudrate} baud')
        self._port, self._packets = port, dynamixel_sdk.PacketHandler(2.0)
        try:
            model, firmware = self._ping()
            self._answered = True
            self.log.info(f'{self._where()}: model number {model}, firmware {firmware}')
            self._write(TORQUE_ENABLE, 1, 0)
            self._torque = False
            self._write(OPERATING_MODE, 1, VELOCITY_CONTROL)
            self.velocity_limit = self._read(VELOCITY_LIMIT, 4)
        except BaseException:
            self.close()
            raise

    def drive(self, frequency):
        """Turn the crank at frequency (Hz): Torque Enable 1 if off, then Goal Velocity."""
        if self.fault is not None:
            return
        goal = goal_velocity_units(frequency, self.gear_ratio)
        if self.velocity_limit is not None and abs(goal) > self.velocity_limit:
            raise InputError(
                f'crank frequency {frequency:g} Hz needs Goal Velocity {goal} '
                f"({goal * VELOCITY_UNIT_RPM:.1f} rev/min at the motor), beyond the servo's "
                f'Velocity Limit {self.velocity_limit}; lower the frequency or check gear_ratio')
        if not self._torque:
            self._write(TORQUE_ENABLE, 1, 1)
            if self.fault is not None:
                return
            self._torque = True
        self._write(GOAL_VELOCITY, 4, goal)

    def stop(self):
        """Goal Velocity 0, then Torque Enable 0."""
        self._write(GOAL_VELOCITY, 4, 0)
        self._write(TORQUE_ENABLE, 1, 0)
        self._torque = False

    def crank_velocity(self):
        """Return the crank angular velocity (rad/s) from Present Velocity."""
        units = signed32(self._read(PRESENT_VELOCITY, 4))
        return crank_angular_velocity(units, self.gear_ratio)

    def close(self):
        """Stop the motor if the port is open (errors are logged, not raised); close the port."""
        if self._port is None:
            return
        self._port.is_using = False       # a transaction interrupted by a signal left it set
        try:
            if self._answered:
                self.stop()
        except Exception as error:
            self.log.error(f'could not stop the servo: {_first_line(error)}')
        finally:
            self._port.closePort()
            self._port = None

    # -- transactions ------------------------------------------------------------------
    def _transact(self, what, call):
        sdk = self._sdk
        for _ in range(RETRIES):
            *answer, result, error = call()
            if result == sdk.COMM_SUCCESS:
                break
            self._port.is_using = False
        else:
            raise InputError(f'{self._where()} does not answer ({what}): check the power, '
                             'cable, ID and baud rate')
        if error & ALERT:
            self._on_alert()
        number = error & ~ALERT
        if number and not (error & ALERT and self.fault):   # a refusal the fault explains
            raise InputError(f'{self._where()} refused {what}: '
                             f'{ERROR_NAMES.get(number, f"error {number}")}')
        return answer

    def _ping(self):
        model, = self._transact('ping', lambda: self._packets.ping(self._port, self.servo_id))
        return model, self._read(FIRMWARE_VERSION, 1)

    def _read(self, address, size):
        def call():
            data, result, error = self._packets.readTxRx(self._port, self.servo_id, address,
                                                         size)
            if result == self._sdk.COMM_SUCCESS and len(data) != size:
                result = self._sdk.COMM_RX_CORRUPT    # a stale status packet of another request
            return data, result, error

        data, = self._transact(f'read {NAMES.get(address, address)}', call)
        return int.from_bytes(bytes(data), 'little')

    def _write(self, address, size, value):
        data = list(int(value).to_bytes(size, 'little', signed=value < 0))
        self._transact(f'{NAMES.get(address, address)} = {value}',
                       lambda: self._packets.writeTxRx(self._port, self.servo_id, address,
                                                       size, data))

    def _on_alert(self):
        """Log the hardware error, stop the motor, and keep it stopped (``fault``)."""
        if self._handling_alert or self.fault is not None:
            return
        self._handling_alert = True
        try:
            status = self._read(HARDWARE_ERROR_STATUS, 1)
            self.fault = (f'hardware error on {self._where()}: {hardware_error_text(status)}; '
                          'motor stopped (power-cycle or reboot the servo to clear it)')
            self.log.error(self.fault)
            self.stop()
        finally:
            self._handling_alert = False


def _first_line(error):
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__
