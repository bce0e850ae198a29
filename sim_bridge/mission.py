"""The simulated vehicle's mission: the MAVLink mission protocol, and flying it in AUTO.

The protocol as ArduPilot answers it (https://mavlink.io/en/services/mission.html):

* **Upload**: MISSION_COUNT, then the vehicle asks for each item in turn (MISSION_REQUEST_INT,
  asked again after :data:`ITEM_TIMEOUT` while it does not come, up to :data:`ITEM_RETRIES`
  times) and ends with MISSION_ACK (ACCEPTED, or the error). Items come as MISSION_ITEM_INT or
  the older MISSION_ITEM (degrees as floats), and are kept as MISSION_ITEM_INT's fields.
* **Download**: MISSION_REQUEST_LIST gets MISSION_COUNT; each MISSION_REQUEST_INT (or
  MISSION_REQUEST) its item in the same form.
* MISSION_CLEAR_ALL, MISSION_SET_CURRENT. Only the mission itself (``mission_type`` 0): a
  geofence or rally upload is refused with MAV_MISSION_UNSUPPORTED, and their lists are empty.

As ArduPilot, item 0 is home (what a planner writes there is kept, not flown), so AUTO starts
at item 1. Flown on the guided flight (:class:`~sim_bridge.profile.GuidedProfile`): NAV_TAKEOFF,
NAV_WAYPOINT (its hold time in param1), NAV_LOITER_TIME, NAV_LAND and NAV_RETURN_TO_LAUNCH; any
other item (DO_* commands) is passed over. Each item reached is reported (MISSION_ITEM_REACHED)
and the next one announced (MISSION_CURRENT).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .mavlink_out import FramePacker
from .profile import GuidedProfile
from .sensors import M_PER_DEG

ITEM_TIMEOUT = 1.0  # [s] of the vehicle's clock before an item is asked for again
ITEM_RETRIES = 5
REACHED = 1.0  # [m] from a waypoint it counts as reached

_GLOBAL_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
}
_AMSL_FRAMES = {mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT}
_ITEM_FIELDS = ("frame", "command", "current", "autocontinue", "param1", "param2", "param3", "param4", "x", "y", "z")


@dataclass
class Item:
    """One mission item as MISSION_ITEM_INT carries it (x, y: degrees x 1e7 in a global frame)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float

    @classmethod
    def of(cls, m) -> Item:
        values = {f: getattr(m, f) for f in _ITEM_FIELDS}
        if m.get_type() == "MISSION_ITEM" and m.frame in _GLOBAL_FRAMES:  # degrees as floats
            values["x"], values["y"] = int(round(m.x * 1e7)), int(round(m.y * 1e7))
        else:
            values["x"], values["y"] = int(round(m.x)), int(round(m.y))
        return cls(seq=m.seq, **values)


class Mission:
    """The mission store and its protocol, and the AUTO mode flying it.

    ``send(frame)`` puts a frame on the link; ``home()`` gives (lat, lon [deg], alt AMSL [m]) of
    the place the vehicle was switched on, where the guided flight's north and east are 0."""

    def __init__(
        self,
        packer: FramePacker,
        send: Callable[[bytes], None],
        sysid: int,
        home: Callable[[], tuple[float, float, float]],
    ) -> None:
        self.packer, self.send, self.sysid, self.home = packer, send, sysid, home
        self.items: list[Item] = []
        self.current = 1  # the item AUTO flies next (0 is home)
        self.reached: list[int] = []
        self.errors = 0  # uploads that failed (timeouts, items out of order)
        self.download_result: int | None = None  # the ground station's MISSION_ACK after a download
        self._upload: dict | None = None  # an upload in progress
        self._item_started: float | None = None  # when the current item was begun (None: not yet)

    # -- the protocol ---------------------------------------------------------------------------
    def on_message(self, m, now: float) -> bool:
        """Handle a mission message addressed to this vehicle; False if it is not one."""
        handler = getattr(self, "_on_" + m.get_type().lower(), None)
        if handler is None:
            return False
        if getattr(m, "target_system", 0) in (0, self.sysid):
            handler(m, now)
        return True

    def _to(self, m) -> dict:
        return {"target_system": m.get_srcSystem(), "target_component": m.get_srcComponent()}

    def _ack(self, m, result: int) -> None:
        self.send(
            self.packer.pack("MISSION_ACK", type=result, mission_type=getattr(m, "mission_type", 0), **self._to(m))
        )

    def _on_mission_request_list(self, m, now: float) -> None:
        n = len(self.items) if getattr(m, "mission_type", 0) == 0 else 0
        self.send(self.packer.pack("MISSION_COUNT", count=n, mission_type=getattr(m, "mission_type", 0), **self._to(m)))

    def _send_item(self, m, integer: bool) -> None:
        if getattr(m, "mission_type", 0) != 0 or not 0 <= m.seq < len(self.items):
            self._ack(m, mavlink.MAV_MISSION_INVALID_SEQUENCE)
            return
        it = self.items[m.seq]
        fields = {f: getattr(it, f) for f in _ITEM_FIELDS}
        if not integer and it.frame in _GLOBAL_FRAMES:
            fields["x"], fields["y"] = it.x / 1e7, it.y / 1e7
        name = "MISSION_ITEM_INT" if integer else "MISSION_ITEM"
        self.send(self.packer.pack(name, seq=it.seq, mission_type=0, **fields, **self._to(m)))

    def _on_mission_request_int(self, m, now: float) -> None:
        self._send_item(m, integer=True)

    def _on_mission_request(self, m, now: float) -> None:
        self._send_item(m, integer=False)

    def _on_mission_count(self, m, now: float) -> None:
        if getattr(m, "mission_type", 0) != 0:
            self._ack(m, mavlink.MAV_MISSION_UNSUPPORTED)
            return
        if m.count == 0:
            self.items, self.current = [], 1
            self._ack(m, mavlink.MAV_MISSION_ACCEPTED)
            return
        self._upload = {"to": m, "count": m.count, "items": [], "asked": now, "tries": 0}
        self._request_next(now)

    def _request_next(self, now: float) -> None:
        up = self._upload
        assert up is not None
        up["asked"] = now
        up["tries"] += 1
        self.send(self.packer.pack("MISSION_REQUEST_INT", seq=len(up["items"]), mission_type=0, **self._to(up["to"])))

    def _on_mission_item_int(self, m, now: float) -> None:
        up = self._upload
        if up is None or getattr(m, "mission_type", 0) != 0:
            return  # not uploading: a late repeat of an item already taken
        if m.seq != len(up["items"]):
            if m.seq > len(up["items"]):  # one was skipped: ask for the one wanted
                self._request_next(now)
            return
        up["items"].append(Item.of(m))
        up["tries"] = 0
        if len(up["items"]) < up["count"]:
            self._request_next(now)
            return
        self.items, self.current, self._upload = up["items"], 1, None
        self._item_started = None
        self._ack(up["to"], mavlink.MAV_MISSION_ACCEPTED)

    _on_mission_item = _on_mission_item_int

    def _on_mission_clear_all(self, m, now: float) -> None:
        if getattr(m, "mission_type", 0) == 0:
            self.items, self.current, self._upload = [], 1, None
        self._ack(m, mavlink.MAV_MISSION_ACCEPTED)

    def _on_mission_set_current(self, m, now: float) -> None:
        if 0 <= m.seq < len(self.items):
            self.current, self._item_started = m.seq, None
            self._announce()

    def _on_mission_ack(self, m, now: float) -> None:
        """The ground station's end of a download: its verdict kept (:attr:`download_result`)."""
        self.download_result = int(m.type)

    def resume(self) -> None:
        """AUTO entered again: begin the current item afresh."""
        self._item_started = None

    def timeouts(self, now: float) -> None:
        """An item asked for that did not come is asked again; after :data:`ITEM_RETRIES` tries the
        upload ends with MISSION_ACK OPERATION_CANCELLED and the old mission stays."""
        up = self._upload
        if up is None or now - up["asked"] < ITEM_TIMEOUT:
            return
        if up["tries"] >= ITEM_RETRIES:
            self._upload = None
            self.errors += 1
            self._ack(up["to"], mavlink.MAV_MISSION_OPERATION_CANCELLED)
        else:
            self._request_next(now)

    # -- flying it ------------------------------------------------------------------------------
    def _announce(self) -> None:
        self.send(self.packer.pack("MISSION_CURRENT", seq=self.current))

    def _north_east(self, it: Item) -> tuple[float, float]:
        lat0, lon0, _ = self.home()
        if it.frame not in _GLOBAL_FRAMES or (it.x == 0 and it.y == 0):
            return math.nan, math.nan  # no position: where it is
        return (
            (it.x / 1e7 - lat0) * M_PER_DEG,
            (it.y / 1e7 - lon0) * M_PER_DEG * math.cos(math.radians(lat0)),
        )

    def _height(self, it: Item) -> float:
        return it.z - self.home()[2] if it.frame in _AMSL_FRAMES else it.z

    def fly(self, profile: GuidedProfile, t: float, on_ground: bool, position: tuple[float, float]) -> None:
        """One step of AUTO: begin the current item, or move on when it is done."""
        if not self.items or self.current >= len(self.items):
            return
        if self.current == 0:
            self.current = 1
        it = self.items[self.current]
        cmd = it.command
        if self._item_started is None:
            self._item_started = t
            self._announce()
            self._begin(it, profile, t)
        if self._done(it, profile, t, on_ground, position):
            self.send(self.packer.pack("MISSION_ITEM_REACHED", seq=self.current))
            self.reached.append(self.current)
            self.current += 1
            self._item_started = None
            if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                self.current = len(self.items)  # landed at home: the mission is over

    def _begin(self, it: Item, profile: GuidedProfile, t: float) -> None:
        cmd = it.command
        n, e = self._north_east(it)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            if profile.armed and not profile.flying:
                profile.takeoff(t, max(0.5, self._height(it)))
        elif cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME):
            if math.isfinite(n):
                profile.go_to(t, n, e)
            if self._height(it) > 0:
                profile.climb_to(t, self._height(it))
        elif cmd == mavlink.MAV_CMD_NAV_LAND:
            if math.isfinite(n):
                profile.go_to(t, n, e)
            else:
                profile.land(t)
        elif cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            profile.go_to(t, 0.0, 0.0)

    def _done(self, it: Item, profile: GuidedProfile, t: float, on_ground: bool, position) -> bool:
        cmd = it.command
        assert self._item_started is not None
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            return profile.flying and profile.arrived(t)
        if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME):
            sp = profile(t)
            close = math.hypot(position[0] - sp.north, position[1] - sp.east) < REACHED
            if not (profile.arrived(t) and close):
                self._item_started = max(self._item_started, t - 1e-9)  # the hold counts from arrival
                return False
            hold = it.param1 if cmd == mavlink.MAV_CMD_NAV_LOITER_TIME or it.param1 > 0 else 0.0
            return t - self._item_started >= hold
        if cmd in (mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            if profile.arrived(t) and not profile.landing:
                profile.land(t)  # over the spot: down
            return profile.landed(t, on_ground) or not profile.armed
        return True  # a command not flown here (DO_*): passed over
