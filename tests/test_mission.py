"""The simulated vehicle's mission protocol at the frame level (real pymavlink frames, encoded and
parsed), with what a lossy link does to it: a lost item asked for again, an item out of order,
an upload given up, the older float form, a geofence it does not keep; and AUTO flying it."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim_bridge.mavlink_out import FramePacker
from sim_bridge.mission import ITEM_RETRIES, ITEM_TIMEOUT, Mission
from sim_bridge.profile import GuidedProfile

HOME = (47.397742, 8.545594, 120.0)
GCS = mavlink.MAVLink(None, 250, 190)


class _Vehicle:
    """The mission on one side, what it sent parsed on the other."""

    def __init__(self) -> None:
        self.parser = mavlink.MAVLink(None)
        self.sent: list = []
        self.mission = Mission(FramePacker(1, 1), self._send, 1, lambda: HOME)

    def _send(self, frame: bytes) -> None:
        self.sent.extend(self.parser.parse_buffer(frame) or ())

    def gets(self, msg, now: float = 0.0) -> list:
        """Hand the vehicle one of the ground station's messages; what it answered."""
        m = self.parser.parse_buffer(bytes(msg.pack(GCS)))[0]
        n = len(self.sent)
        assert self.mission.on_message(m, now)
        return self.sent[n:]


def _item(seq: int, cmd: int, lat: float = 0.0, lon: float = 0.0, alt: float = 0.0, mission_type: int = 0):
    frame = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    x, y = int(round(lat * 1e7)), int(round(lon * 1e7))
    return mavlink.MAVLink_mission_item_int_message(1, 1, seq, frame, cmd, 0, 1, 0, 0, 0, 0, x, y, alt, mission_type)


PLAN = [
    _item(0, mavlink.MAV_CMD_NAV_WAYPOINT, HOME[0], HOME[1], 0.0),  # home
    _item(1, mavlink.MAV_CMD_NAV_TAKEOFF, alt=3.0),
    _item(2, mavlink.MAV_CMD_NAV_WAYPOINT, HOME[0] + 4 / 111_320, HOME[1], 3.0),
    _item(3, mavlink.MAV_CMD_NAV_LAND),
]


def _upload(v: _Vehicle, items=PLAN) -> list:
    out = v.gets(mavlink.MAVLink_mission_count_message(1, 1, len(items), 0))
    for it in items:
        out += v.gets(it)
    return out


def test_an_upload_is_asked_item_by_item_acknowledged_and_read_back_in_both_forms():
    v = _Vehicle()
    out = _upload(v)
    assert [m.seq for m in out if m.get_type() == "MISSION_REQUEST_INT"] == [0, 1, 2, 3]
    assert out[-1].get_type() == "MISSION_ACK" and out[-1].type == mavlink.MAV_MISSION_ACCEPTED
    assert out[-1].target_system == 250 and out[-1].target_component == 190
    (count,) = v.gets(mavlink.MAVLink_mission_request_list_message(1, 1, 0))
    assert count.count == 4
    (back,) = v.gets(mavlink.MAVLink_mission_request_int_message(1, 1, 2, 0))
    assert back.get_type() == "MISSION_ITEM_INT" and back.x == PLAN[2].x and back.z == 3.0
    (old,) = v.gets(mavlink.MAVLink_mission_request_message(1, 1, 2, 0))
    assert old.get_type() == "MISSION_ITEM" and abs(old.x - PLAN[2].x / 1e7) < 1e-6
    (bad,) = v.gets(mavlink.MAVLink_mission_request_int_message(1, 1, 9, 0))
    assert bad.get_type() == "MISSION_ACK" and bad.type == mavlink.MAV_MISSION_INVALID_SEQUENCE
    assert v.gets(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_ACCEPTED, 0)) == []
    assert v.mission.download_result == mavlink.MAV_MISSION_ACCEPTED  # the download's end, as the GCS saw it


def test_a_lost_item_is_asked_again_and_an_item_ahead_of_its_turn_is_not_taken():
    v = _Vehicle()
    v.gets(mavlink.MAVLink_mission_count_message(1, 1, 4, 0), now=0.0)
    v.gets(PLAN[0], now=0.1)  # item 1 is lost on the way; item 2 arrives ahead of its turn
    (again,) = v.gets(PLAN[2], now=0.2)
    assert again.get_type() == "MISSION_REQUEST_INT" and again.seq == 1
    n = len(v.sent)
    v.mission.timeouts(0.2 + ITEM_TIMEOUT)  # still nothing: asked once more
    assert [m.seq for m in v.sent[n:]] == [1]
    for it in PLAN[1:]:
        v.gets(it, now=1.5)
    assert v.sent[-1].type == mavlink.MAV_MISSION_ACCEPTED and len(v.mission.items) == 4


def test_an_upload_that_stalls_is_given_up_and_the_old_mission_kept():
    v = _Vehicle()
    _upload(v)
    v.gets(mavlink.MAVLink_mission_count_message(1, 1, 3, 0), now=10.0)
    for k in range(ITEM_RETRIES):
        v.mission.timeouts(10.0 + (k + 1) * ITEM_TIMEOUT)
    assert v.sent[-1].get_type() == "MISSION_ACK" and v.sent[-1].type == mavlink.MAV_MISSION_OPERATION_CANCELLED
    assert len(v.mission.items) == 4 and v.mission.errors == 1


def test_a_geofence_is_refused_and_its_list_is_empty():
    v = _Vehicle()
    fence = mavlink.MAV_MISSION_TYPE_FENCE
    (ack,) = v.gets(mavlink.MAVLink_mission_count_message(1, 1, 5, fence))
    assert ack.type == mavlink.MAV_MISSION_UNSUPPORTED
    (count,) = v.gets(mavlink.MAVLink_mission_request_list_message(1, 1, fence))
    assert count.count == 0 and count.mission_type == fence


def test_auto_takes_off_flies_to_the_waypoint_and_lands():
    """The mission flown on the guided flight's setpoints, the vehicle following them exactly."""
    v = _Vehicle()
    _upload(v)
    g = GuidedProfile()
    g.armed = True
    t, pos = 0.0, (0.0, 0.0)
    while t < 60.0 and g.armed:
        sp = g(t)
        pos = (sp.north, sp.east)
        v.mission.fly(g, t, on_ground=sp.height <= 0.0, position=pos)
        t += 0.05
    assert not g.armed and v.mission.reached == [1, 2, 3]  # landed, disarmed, every item reached
    assert abs(pos[0] - 4.0) < 0.05 and abs(pos[1]) < 0.05  # where the landing was: the waypoint
    reached = [m.seq for m in v.sent if m.get_type() == "MISSION_ITEM_REACHED"]
    assert reached == [1, 2, 3]


def test_auto_without_a_mission_is_refused_on_the_guided_flight():
    """As ArduCopter: AUTO needs a mission past home (item 0); with one uploaded it is taken."""
    from sim_bridge.scenario import Scenario
    from sim_bridge.simulator import Simulator
    from sim_bridge.vehicle_protocol import MODE_AUTO, MODE_GUIDED, VehicleProtocol

    v = _Vehicle()
    protocol = VehicleProtocol(Simulator(Scenario("quad", flight="guided")), FramePacker(1, 1), v._send, 1)
    assert protocol.set_mode(MODE_AUTO) == mavlink.MAV_RESULT_DENIED and protocol.mode == MODE_GUIDED
    protocol.mission = v.mission
    _upload(v)
    assert protocol.set_mode(MODE_AUTO) == mavlink.MAV_RESULT_ACCEPTED and protocol.mode == MODE_AUTO
