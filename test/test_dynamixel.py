"""The Protocol 2.0 emulator against the e-Manual, and the Dynamixel driver against it.

The emulator is written from the e-Manual's packet format, not from dynamixel-sdk's packet
code; its packets are checked here byte for byte against the e-Manual's worked examples, so
the driver's (and the SDK's) behaviour is checked against an independent implementation.
"""

import math

from dynamixel_sdk import COMM_RX_TIMEOUT, PacketHandler, PortHandler
import pytest
import serial

from microball_ros.core.errors import InputError
from microball_ros.io.dynamixel import (
    DynamixelDriver,
    crank_angular_velocity,
    goal_velocity_units,
    signed32,
)
from microball_ros.testing.dynamixel_emulator import (
    GOAL_VELOCITY,
    HARDWARE_ERROR_STATUS,
    OPERATING_MODE,
    TORQUE_ENABLE,
    DynamixelEmulator,
    crc16,
    packet,
    parse,
    status_packet,
    stuff,
    unstuff,
)

# Worked examples of the ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0" (ID 1 is an XM430-W210:
# model number 1030, firmware 38).
EMANUAL = [
    # Ping, and ID 1's status packet.
    ((1, 0x01, ''), 'FF FF FD 00 01 03 00 01 19 4E'),
    ((1, 0x55, '00 06 04 26'), 'FF FF FD 00 01 07 00 55 00 06 04 26 65 5D'),
    # Ping to the broadcast ID, and ID 2's status packet.
    ((0xFE, 0x01, ''), 'FF FF FD 00 FE 03 00 01 31 42'),
    ((2, 0x55, '00 06 04 26'), 'FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D'),
    # Read Present Position (132, 4 bytes) = 166, and the status packet.
    ((1, 0x02, '84 00 04 00'), 'FF FF FD 00 01 07 00 02 84 00 04 00 1D 15'),
    ((1, 0x55, '00 A6 00 00 00'), 'FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0'),
    # Write 512 to Goal Position (116, 4 bytes), and the status packet.
    ((1, 0x03, '74 00 00 02 00 00'), 'FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89'),
    ((1, 0x55, '00'), 'FF FF FD 00 01 04 00 55 00 A1 0C'),
    # Reg Write 200 to Goal Velocity (104, 4 bytes).
    ((1, 0x04, '68 00 C8 00 00 00'), 'FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E'),
    # Sync Write Goal Position: 150 to ID 1, 170 to ID 2.
    ((0xFE, 0x83, '74 00 04 00 01 96 00 00 00 02 AA 00 00 00'),
     'FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87'),
]


@pytest.mark.parametrize('fields,expected', EMANUAL)
def test_packets_match_the_emanual_worked_examples(fields, expected):
    servo_id, instruction, params = fields
    expected = bytes.fromhex(expected)
    assert packet(servo_id, instruction, bytes.fromhex(params)) == expected
    if instruction == 0x55:
        error, *data = bytes.fromhex(params)
        assert status_packet(servo_id, error, bytes(data)) == expected
    assert crc16(expected[:-2]) == int.from_bytes(expected[-2:], 'little')
    parsed, rest = parse(b'\x00\xff' + expected + b'\xff')
    assert parsed == (servo_id, instruction, bytes.fromhex(params)) and rest == b'\xff'


def test_crc_is_crc16_buypass_and_detects_a_flipped_bit():
    # CRC-16 with polynomial 0x8005, initial 0, unreflected: the catalogue's check value.
    assert crc16(b'123456789') == 0xFEE8
    good = bytes.fromhex('FF FF FD 00 01 03 00 01 19 4E')
    bad = good[:7] + bytes([good[7] ^ 0x10]) + good[8:]
    assert parse(bad) == ('bad', b'')


def test_byte_stuffing_inserts_fd_after_the_header_pattern_and_counts_it_in_length():
    body = bytes.fromhex('03 74 00 FF FF FD 00')
    assert stuff(body) == bytes.fromhex('03 74 00 FF FF FD FD 00')
    assert unstuff(stuff(body)) == body
    whole = packet(1, 0x03, body[1:])
    assert int.from_bytes(whole[5:7], 'little') == len(stuff(body)) + 2
    assert parse(whole)[0] == (1, 0x03, body[1:])


def test_emulator_answers_the_emanual_ping_byte_for_byte():
    with DynamixelEmulator(model_number=1030, firmware=38) as servo:
        with serial.Serial(servo.port, 57600, timeout=5) as link:
            good = bytes.fromhex('FF FF FD 00 01 03 00 01 19 4E')
            corrupt = good[:-1] + b'\x4f'
            link.write(corrupt + good)                 # a corrupt packet gets no answer
            answer = link.read(14)
            assert servo.packets_received == 1
    assert answer == bytes.fromhex('FF FF FD 00 01 07 00 55 00 06 04 26 65 5D')


@pytest.fixture
def sdk():
    """Give an emulated servo with dynamixel-sdk's port and Protocol 2.0 handler on it."""
    with DynamixelEmulator() as servo:
        port = PortHandler(servo.port)
        assert port.openPort() and port.setBaudRate(57600)
        try:
            yield servo, port, PacketHandler(2.0)
        finally:
            port.closePort()


def test_emulator_serves_the_sdk_like_an_x_series_servo(sdk):
    servo, port, packets = sdk
    assert packets.ping(port, 1) == (1020, 0, 0)
    assert packets.ping(port, 2)[1] == COMM_RX_TIMEOUT          # nobody has ID 2
    assert packets.write1ByteTxRx(port, 1, 11, 1) == (0, 0)     # mode with torque off
    assert packets.write1ByteTxRx(port, 1, 64, 1) == (0, 0)
    assert packets.write1ByteTxRx(port, 1, 11, 3) == (0, 7)     # ROM lock: access error
    assert servo.get(OPERATING_MODE) == 1
    assert packets.write4ByteTxRx(port, 1, 104, -200 & 0xFFFFFFFF) == (0, 0)
    value, result, error = packets.read4ByteTxRx(port, 1, 128)  # present follows goal
    assert (signed32(value), result, error) == (-200, 0, 0)
    assert packets.write4ByteTxRx(port, 1, 104, 2000) == (0, 6)  # beyond Velocity Limit
    assert servo.get(GOAL_VELOCITY) == -200
    # Data that contains the header pattern goes through stuffing on both sides.
    assert packets.write4ByteTxRx(port, 1, 116, 0x00FDFFFF) == (0, 0)
    assert servo.writes[-1].data == bytes.fromhex('FF FF FD 00')
    assert packets.read4ByteTxRx(port, 1, 116) == (0x00FDFFFF, 0, 0)
    assert [(w.address, w.value, w.accepted) for w in servo.writes] == [
        (11, 1, True), (64, 1, True), (11, 3, False), (104, -200, True), (104, 2000, False),
        (116, 0x00FDFFFF, True)]
    times = [w.time for w in servo.writes]
    assert times == sorted(times)


def test_emulator_hardware_error_sets_alert_and_drops_torque(sdk):
    servo, port, packets = sdk
    packets.write1ByteTxRx(port, 1, 11, 1)
    packets.write1ByteTxRx(port, 1, 64, 1)
    servo.inject_hardware_error()
    assert packets.read1ByteTxRx(port, 1, 70) == (0x04, 0, 0x80)
    assert packets.read1ByteTxRx(port, 1, 64) == (0, 0, 0x80)
    assert packets.write1ByteTxRx(port, 1, 64, 1) == (0, 0x81)     # torque stays off
    servo.silent = True
    assert packets.ping(port, 1)[1] == COMM_RX_TIMEOUT


class Log:
    """A logger that keeps what it was told."""

    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(('info', text))

    def warning(self, text):
        self.lines.append(('warning', text))

    def error(self, text):
        self.lines.append(('error', text))


def _driver(port, gear_ratio=1.0, servo_id=1):
    values = {'port': port, 'baudrate': 57600, 'servo_id': servo_id, 'gear_ratio': gear_ratio}
    return DynamixelDriver(values, Log())


def test_goal_velocity_units_and_crank_speed():
    # 60 * f / gear_ratio / 0.229, rounded: 0.5 Hz through 2 crank turns per motor turn.
    assert goal_velocity_units(0.5, 2.0) == 66                  # 65.50
    assert goal_velocity_units(2.95, 1.0) == 773                # 772.93
    assert goal_velocity_units(-1.0, 0.5) == -524               # -524.02
    assert crank_angular_velocity(100, 2.0) == pytest.approx(100 * 0.229 * 2 * 2 * math.pi / 60)
    assert signed32(0xFFFFFF85) == -123 and signed32(123) == 123


def test_driver_sequence_torque_off_mode_torque_on_goal_then_stop():
    with DynamixelEmulator() as servo:
        servo.set(TORQUE_ENABLE, 1)            # left running by a crashed process
        driver = _driver(servo.port, gear_ratio=2.0)
        driver.open()
        assert driver.max_frequency == pytest.approx(1023 * 0.229 * 2.0 / 60)
        driver.drive(0.5)
        servo.set_present_velocity(-123)
        assert driver.crank_velocity() == pytest.approx(-123 * 0.229 * 2.0 * 2 * math.pi / 60)
        driver.stop()
        driver.close()
        assert [(w.address, w.value, w.accepted) for w in servo.writes] == [
            (64, 0, True), (11, 1, True), (64, 1, True), (104, 66, True),
            (104, 0, True), (64, 0, True), (104, 0, True), (64, 0, True)]
        assert servo.get(OPERATING_MODE) == 1 and servo.get(TORQUE_ENABLE) == 0


def test_driver_refuses_a_frequency_beyond_the_velocity_limit():
    with DynamixelEmulator(velocity_limit=200) as servo:
        driver = _driver(servo.port)
        driver.open()
        with pytest.raises(InputError, match='Velocity Limit 200'):
            driver.drive(2.95)                  # 773 units
        driver.close()
        assert all(w.address != 104 or w.value == 0 for w in servo.writes)


def test_driver_stops_the_motor_on_a_hardware_error():
    with DynamixelEmulator() as servo:
        driver = _driver(servo.port)
        driver.open()
        driver.drive(1.0)
        servo.inject_hardware_error()
        before = len(servo.writes)
        driver.crank_velocity()
        assert 'overheating' in driver.fault
        assert [(w.address, w.value) for w in servo.writes[before:]] == [(104, 0), (64, 0)]
        assert [level for level, text in driver.log.lines if 'overheating' in text] == ['error']
        driver.drive(1.0)                       # no restart after a fault
        assert len(servo.writes) == before + 2
        assert servo.get(HARDWARE_ERROR_STATUS) == 0x04
        driver.close()


def test_driver_says_in_one_line_when_the_servo_is_silent_or_the_port_missing(tmp_path):
    with DynamixelEmulator() as servo:
        servo.silent = True
        driver = _driver(servo.port)
        with pytest.raises(InputError, match='does not answer') as caught:
            driver.open()
        assert '\n' not in str(caught.value)
        assert servo.writes == [] and driver.log.lines == []
        wrong_id = _driver(servo.port, servo_id=7)
        servo.silent = False
        with pytest.raises(InputError, match='Dynamixel ID 7 .* does not answer'):
            wrong_id.open()
    missing = str(tmp_path / 'ttyUSB9')
    with pytest.raises(InputError, match='does not exist'):
        _driver(missing).open()
    with pytest.raises(InputError, match='needs the port'):
        _driver('').open()
