"""Test doubles for users and the project's own tests (e.g. a Dynamixel servo emulator)."""
