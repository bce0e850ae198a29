"""What the simulator offers, by name, loaded before the simulator itself (the command line's
choices): its vehicles, its built-in flights, its streams' rate until a ground station asks."""

from __future__ import annotations

VEHICLES = ("quad", "coax", "heli3dof")
FLIGHTS = ("standard", "thrust_test", "high", "guided", "small", "large")
#: the flights only the 3-DOF helicopter flies (near its linearisation point, and far from it)
RIG_FLIGHTS = ("small", "large")
#: [Hz] each stream's rate over MAVLink until a ground station asks for it (SET_MESSAGE_INTERVAL
#: or REQUEST_DATA_STREAM), as an autopilot starts at its low default stream rates (ArduPilot's
#: SRn_* parameters: 0-4 Hz); the sensors themselves sample at their own rates all along
UNASKED_RATE = 2.0
