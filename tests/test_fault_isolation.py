"""A fault in one part takes nothing else down: a recording that fails stops and says so while
telemetry, estimation and the link's state go on (the full disk is real: Linux's /dev/full answers
every write with ENOSPC); a consumer that raises is counted and the link delivers on; a session's
task that raises is reported and restarted, or stops the session when it keeps failing."""

import asyncio
import os
import subprocess
import sys

import pytest

from drivers.link_state import LinkState
from drivers.mavlink.link import MavlinkLink
from groundstation.core.measurement import Kind
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.registry import build_estimator
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario

from .conftest import async_test

FULL = "/dev/full"
needs_dev_full = pytest.mark.skipif(not os.path.exists(FULL), reason="no /dev/full on this system")


@pytest.mark.slow
@needs_dev_full
@async_test(timeout=60)
async def test_a_full_disk_stops_the_recording_and_nothing_else():
    link = MavlinkLink("udpin:127.0.0.1:0", record=FULL)
    events, ms = link.events(), link.measurements()
    loop = EstimationLoop([build_estimator("altitude", declared=[{"name": "range_tilt"}])])
    loop.attach_link(link)
    await link.open()
    bridge = SimBridge(Scenario("quad", seed=2, duration=30.0), udp_to=("127.0.0.1", link.transport.local_address[1]))
    await bridge.open()
    flying = asyncio.create_task(bridge.run())
    try:
        why = None
        async for ev in events:  # the first flush (0.5 s) meets the full disk
            if "recording" in ev.reason:
                why = ev.reason
                break
        assert "stopped" in why and "No space left on device" in why, why
        assert link.recorder.error == why and link.state is LinkState.ALIVE
        n_before, seen = loop.counters.processed, 0
        async for m in ms:  # the link goes on delivering, the estimator on estimating
            seen += m.kind is Kind.RANGE
            if seen >= 25:
                break
        assert loop.counters.processed > n_before and link.state is LinkState.ALIVE
        assert loop.latest["altitude"].t > 0.0
    finally:
        bridge.close()
        await asyncio.gather(flying, return_exceptions=True)
        await link.close()


@pytest.mark.slow
@needs_dev_full
def test_connect_on_a_full_disk_says_so_in_one_line_and_keeps_estimating(tmp_path):
    """The command line: the recording's failure is one line (no traceback), the session runs to its
    end, and the closing line says what happened to the recording."""
    from .conftest import free_udp_port

    port = free_udp_port()
    sim = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "groundstation",
            "sim",
            "--vehicle",
            "quad",
            "--udp",
            f"127.0.0.1:{port}",
            "--duration",
            "20",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "groundstation",
                "connect",
                f"udpin:127.0.0.1:{port}",
                "--record",
                FULL,
                "--no-web",
                "--duration",
                "4",
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        sim.terminate()
        sim.wait(timeout=10)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr + r.stdout
    assert "recording to /dev/full stopped after" in r.stdout and "No space left on device" in r.stdout
    closing = r.stdout.strip().splitlines()[-1]
    assert closing.startswith("closed: ") and "stopped after" in closing, closing


@async_test(timeout=60)
async def test_a_consumer_that_raises_is_counted_and_the_link_delivers_on():
    link = MavlinkLink("udpin:127.0.0.1:0")
    events, ms = link.events(), link.measurements()
    calls = []

    def broken(batch):
        calls.append(len(batch))
        raise RuntimeError("a broken consumer")

    link.sinks.append(broken)
    await link.open()
    bridge = SimBridge(Scenario("quad", seed=2, duration=30.0), udp_to=("127.0.0.1", link.transport.local_address[1]))
    await bridge.open()
    flying = asyncio.create_task(bridge.run())
    try:
        said = [ev.reason async for ev in _until(events, lambda ev: "consumer" in ev.reason)]
        assert said[-1] == "a consumer of the link failed: RuntimeError: a broken consumer"
        seen = 0
        async for _ in ms:
            seen += 1
            if seen > 500:
                break
        assert link.counters.sink_errors >= 2 and len(calls) == link.counters.sink_errors
        assert link.state is LinkState.ALIVE
    finally:
        bridge.close()
        await asyncio.gather(flying, return_exceptions=True)
        await link.close()


async def _until(stream, done):
    async for item in stream:
        yield item
        if done(item):
            return


@async_test(timeout=20)
async def test_a_failing_task_is_reported_and_restarted_and_one_that_keeps_failing_stops_the_session():
    import io

    from groundstation.app.supervise import MAX_FAILURES, Supervisor

    out, stopped, runs = io.StringIO(), asyncio.Event(), []

    async def flaky():
        runs.append(1)
        if len(runs) == 1:
            raise ValueError("once")

    sup = Supervisor(stopped.set, out=out)
    await sup.start("flaky", flaky)
    assert len(runs) == 2 and "groundstation: flaky failed: ValueError: once; restarted" in out.getvalue()
    assert not stopped.is_set() and sup.fatal is None

    async def broken():
        raise OSError("always")

    await sup.start("broken", broken)
    assert stopped.is_set() and sup.fatal.startswith("broken failed: OSError: always")
    assert f"({MAX_FAILURES} times in" in out.getvalue().splitlines()[-1]
