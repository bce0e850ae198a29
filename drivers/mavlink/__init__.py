"""MAVLink vehicles: live links (UDP, TCP, serial) and the message-to-measurement decoder."""

from .decode import MavlinkDecoder
from .link import LinkEvent, LinkState, MavlinkLink
from .receiver import LinkCounters, MavlinkReceiver

__all__ = ["MavlinkDecoder", "MavlinkLink", "MavlinkReceiver", "LinkCounters", "LinkEvent", "LinkState"]
