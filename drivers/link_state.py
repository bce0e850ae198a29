"""Link state, shared by every live source (MAVLink links, sensor boards)."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class LinkState(enum.Enum):
    CONNECTING = "connecting"  # opened, nothing valid received yet
    ALIVE = "alive"
    LOST = "lost"
    CLOSED = "closed"


@dataclass(frozen=True)
class LinkEvent:
    state: LinkState
    t: float  # wall-clock time of the change
    reason: str
