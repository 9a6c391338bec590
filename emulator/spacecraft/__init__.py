"""Spacecraft emulator: rigid body + four reaction wheels (Yoon 2017, Ch. 4 and 6), environment, devices.

- ``wheels``: pyramid geometry and misalignment (Eq. 4.147-4.149), rotor, limits, friction, read-out, jitter.
- ``dynamics``: quaternion kinematics (Eq. 4.10) and Euler's equation with wheels (Eq. 4.16), fixed-step RK4.
- ``environment``: circular orbit, tilted-dipole field, gravity-gradient and magnetic torques (Eq. 4.69-4.75).
- ``devices``: RW0..RW3 and the star tracker on the protocol (RW_CMD -> RW_TLM, STARTRACKER).
"""

from emulator.spacecraft.devices import SpacecraftDevices, StarTracker
from emulator.spacecraft.dynamics import Spacecraft
from emulator.spacecraft.wheels import WheelParams, Wheels

__all__ = ["Spacecraft", "SpacecraftDevices", "StarTracker", "WheelParams", "Wheels"]
