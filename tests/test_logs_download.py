"""Logs from the vehicle: the simulated vehicle keeps a DataFlash log of each flight, written as
ArduPilot writes them, and serves it over MAVLink's log protocol; the ground station lists and
downloads it over real loopback UDP, byte for byte through a link that loses a fifth of the
vehicle's frames, and the log reads, triages and diagnoses like any other."""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys

import pytest
from pymavlink import DFReader

from drivers.logs.dataflash import read_dataflash
from drivers.logs.dataflash_writer import DataFlashWriter
from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.log_transfer import LogClient, LogEntry, LogTransferError
from groundstation.core.measurement import Kind
from sim_bridge.bridge import LinkFaults, SimBridge
from sim_bridge.scenario import Scenario

from .conftest import async_test, free_udp_port
from .helpers import simulated_vehicle


def test_the_writer_packs_each_field_code_and_scale_as_pymavlink_reads_them(tmp_path):
    f = tmp_path / "w.bin"
    with open(f, "wb") as out:
        w = DataFlashWriter(out)
        w.define("GPS", "QBcLLeCfN", "TimeUS,Status,HDop,Lat,Lng,Alt,Dist,Spd,Name")
        w.write("GPS", 1_500_000, 3, 0.87, 47.3977419, 8.5455938, 488.25, 3.21, 1.5, "HELLO")
        w.define("PARM", "QNf", "TimeUS,Name,Value")
        w.write("PARM", 0, "RNGFND1_MIN_CM", 20.0)
        with pytest.raises(ValueError, match="defined twice"):
            w.define("GPS", "Q", "TimeUS")
        with pytest.raises(ValueError, match="one column a code"):
            w.define("BAD", "QB", "TimeUS")
    r = DFReader.DFReader_binary(str(f))
    m = r.recv_match(type="GPS")
    assert (m.TimeUS, m.Status, m.HDop, m.Name) == (1_500_000, 3, pytest.approx(0.87), "HELLO")
    assert m.Lat == pytest.approx(47.3977419, abs=1e-7) and m.Lng == pytest.approx(8.5455938, abs=1e-7)
    assert m.Alt == pytest.approx(488.25) and m.Dist == pytest.approx(3.21) and m.Spd == pytest.approx(1.5)
    assert r.params["RNGFND1_MIN_CM"] == 20.0


def _flown(seconds: float, **faults) -> SimBridge:
    """A simulated quad that flew ``seconds`` (its standard flight arms at 2 s) and then landed: its
    first log closed (the flight after it opens the second)."""
    br = SimBridge(Scenario("quad", seed=4), udp_to=("127.0.0.1", 9), faults=LinkFaults(**faults))
    br._tick(seconds)  # the world faster than real time, before anyone listens
    br.flight_logs.close()
    return br


@contextlib.asynccontextmanager
async def _on_link(br: SimBridge):
    """A link on a free port with ``br`` sending to it and running, once its first heartbeat has
    come; the vehicle stopped and the link closed on the way out, also when the test fails."""
    link = MavlinkLink("udpin:127.0.0.1:0", streams={})
    await link.open()
    br.udp_to = ("127.0.0.1", link.transport.local_address[1])
    await br.open()
    task = asyncio.get_running_loop().create_task(br.run())
    try:
        while 1 not in link.vehicles:  # (the heartbeat goes out with the first step)
            await asyncio.sleep(0.02)
        yield link
    finally:
        br.close()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await link.close()


def test_each_flight_is_a_dataflash_log_that_reads_as_the_vehicle_flew(tmp_path):
    br = _flown(20.0)
    log = br.flight_logs.logs[1]
    assert not log.open and log.time_utc == pytest.approx(br.flight_logs.epoch + 2.0, abs=0.01)
    f = tmp_path / "flight.bin"
    f.write_bytes(log.data)
    d = read_dataflash(f)
    kinds = {m.kind for m in d.measurements}
    assert {Kind.ACCEL, Kind.GYRO, Kind.BARO_ALTITUDE, Kind.GPS, Kind.RANGE, Kind.ACTUATOR, Kind.THROTTLE} <= kinds
    assert {Kind.BATTERY_VOLTAGE, Kind.ATTITUDE} <= kinds
    acc = [m.value for m in d.measurements if m.kind is Kind.ACCEL]
    assert acc[0][2] == pytest.approx(-9.81, abs=0.5)  # FRD: at rest the specific force points up
    assert d.tables.params["SIM_ALPHA"] == pytest.approx(22.0) and d.tables.params["RNGFND1_MAX_CM"] == 400
    assert "ArduCopter" in d.tables.firmware
    assert 2.0 <= d.measurements[0].t < 2.1 and d.measurements[-1].t == pytest.approx(20.0, abs=0.05)


@pytest.mark.slow
@async_test(timeout=90)
async def test_a_log_downloads_byte_for_byte_at_twenty_percent_loss():
    br = _flown(25.0, loss=0.2)
    async with _on_link(br) as link:
        client = LogClient(link, 1, timeout=0.5)
        entries = await client.list()  # the first flight's log, and the one now being written
        assert [e.id for e in entries] == [1, 2] and client.num_logs == 2
        want = bytes(br.flight_logs.logs[1].data)
        assert entries[0] == LogEntry(1, int(br.flight_logs.logs[1].time_utc), len(want))
        dropped = br.frames_dropped
        seen: list[tuple[int, int]] = []
        got = await client.download(entries[0], lambda n, total: seen.append((n, total)))
        assert got == want and len(want) > 400_000
        assert br.frames_dropped - dropped > 0.15 * len(want) / 90  # a fifth of the LOG_DATA was lost
        counts = [n for n, _ in seen]
        assert seen[-1] == (len(want), len(want)) and counts == sorted(counts)
        with pytest.raises(LogTransferError, match="log 9: 0 of 900 bytes"):  # nothing comes for a log it lacks
            await client.download(LogEntry(9, 0, 900))
        await client.erase()  # (its datagram reaches the vehicle before the list's, on loopback in order)
        assert [e.id for e in await client.list()] == [2]  # the open log stays, as ArduPilot's
        client.close()


@async_test(timeout=60)
async def test_a_download_the_vehicle_stops_serving_keeps_what_came_before_the_first_gap():
    br = _flown(10.0, loss=0.2)
    serve, asked = br.log_server.on_log_request_data, []

    def first_only(m):  # the vehicle serves the first request and then goes quiet (its logging busy)
        asked.append(m)
        if len(asked) == 1:
            serve(m)

    br.log_server.on_log_request_data = first_only
    async with _on_link(br) as link:
        client = LogClient(link, 1, timeout=0.5)
        (entry, *_) = await client.list()
        with pytest.raises(LogTransferError, match=f"log 1: [0-9]+ of {entry.size} bytes received") as e:
            await client.download(entry)
        want = bytes(br.flight_logs.logs[1].data)
        assert want.startswith(e.value.partial) and len(e.value.partial) < len(want) and len(asked) > 1


@async_test(timeout=60)
async def test_a_vehicle_that_keeps_no_logs_is_a_one_line_error():
    br = SimBridge(Scenario("quad", seed=4), udp_to=("127.0.0.1", 9))
    br.log_server.on_log_request_list = lambda m: None  # a vehicle without the log protocol: no answer
    async with _on_link(br) as link:
        client = LogClient(link, 1, timeout=0.2)
        with pytest.raises(LogTransferError, match="did not answer LOG_REQUEST_LIST"):
            await client.list()


@pytest.mark.slow
def test_logs_command_lists_downloads_the_latest_and_it_triages(tmp_path):
    """``groundstation logs`` against ``groundstation sim`` losing a fifth of its frames (two
    processes on loopback, both stopped by the test)."""
    port = free_udp_port()
    gs = [sys.executable, "-m", "groundstation"]
    logs = [*gs, "logs", f"udpin:127.0.0.1:{port}"]
    with simulated_vehicle(port, "--speed", "4", "--loss", "0.2", "--duration", "120"):
        for _ in range(20):  # until the vehicle has armed (its flight arms 2 s in): each list waits on its answer
            r = subprocess.run(logs + ["list"], capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, r.stderr
            if "no logs" not in r.stdout:
                break
        assert "vehicle 1: 1 logs" in r.stdout and "2026-01-01 00:00:02 UTC" in r.stdout
        r = subprocess.run(logs + ["download", "7"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and r.stderr.strip() == "groundstation: error: no log 7 on the vehicle (it has 1)"
        out = tmp_path / "last.bin"
        r = subprocess.run(logs + ["latest", "--out", str(out)], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and f"-> {out}" in r.stdout, r.stderr
        r = subprocess.run(logs + ["erase"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "add --yes" in r.stderr
    r = subprocess.run([*gs, "triage", str(out)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "ArduPilot DataFlash log" in r.stdout, r.stderr
