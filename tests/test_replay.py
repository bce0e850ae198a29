"""Replay: speed, pause/resume, seek and loop, through the live receive path."""

import asyncio
import math
import time

import pytest

from drivers.replay import Replay, ReplayState
from groundstation.core.measurement import Kind

from .conftest import async_test
from .helpers import imu_frames, write_tlog


@pytest.fixture
def two_seconds(tmp_path):
    return write_tlog(tmp_path / "two.tlog", imu_frames(200), dt=0.01)  # 200 records over 1.99 s


@async_test()
async def test_speed_paces_playback(two_seconds):
    rp = Replay(two_seconds, speed=10.0)
    sub = rp.measurements()
    t0 = time.monotonic()
    await rp.run()
    elapsed = time.monotonic() - t0
    got = sub.get_nowait()
    assert len(got) == 600
    assert 0.18 <= elapsed < 2.0  # 1.99 s of recording at 10x


@async_test()
async def test_max_speed_is_lossless_with_a_slow_consumer(two_seconds):
    rp = Replay(two_seconds, speed=math.inf, buffer=64)
    sub = rp.measurements()
    n = 0

    async def slow():
        nonlocal n
        async for _ in sub:
            n += 1
            if n % 50 == 0:
                await asyncio.sleep(0)

    await asyncio.gather(rp.run(), slow())
    assert n == 600 and sub.dropped == 0


@async_test()
async def test_pause_holds_and_resume_continues(two_seconds):
    rp = Replay(two_seconds, speed=math.inf)
    sub = rp.measurements()
    rp.pause()
    task = asyncio.create_task(rp.run())
    for _ in range(20):  # event-loop turns, no wall-clock wait
        await asyncio.sleep(0)
    assert sub.backlog == 0 and rp.status.state is ReplayState.PAUSED
    rp.resume()
    await task
    assert len(sub.get_nowait()) == 600 and rp.status.state is ReplayState.ENDED


@async_test()
async def test_seek_jumps_by_recording_time(two_seconds):
    rp = Replay(two_seconds, speed=math.inf)
    rp.seek(1.495)
    assert rp.position == pytest.approx(1.5, abs=1e-3)
    sub = rp.measurements()
    await rp.run()
    ts = [m.t for m in sub.get_nowait() if m.kind is Kind.ACCEL]
    assert len(ts) == 50 and ts[0] == pytest.approx(1.0 + 1.5, abs=0.011)  # vehicle time 2.5 s


@async_test()
async def test_loop_plays_again(two_seconds):
    rp = Replay(two_seconds, speed=math.inf, loop=True)
    sub = rp.measurements()
    task = asyncio.create_task(rp.run())
    n = 0
    async for _ in sub:
        n += 1
        if n == 1500:  # two and a half passes
            break
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert n == 1500


def test_speed_limits():
    with pytest.raises(ValueError):
        from drivers.speed import check_speed

        check_speed(1000)


@async_test()
async def test_typed_replay_commands(two_seconds):
    from groundstation.app.console import replay_command

    rp = Replay(two_seconds, speed=1.0)
    stop = asyncio.Event()
    assert replay_command("p", rp, stop) == "paused" and rp.status.state is ReplayState.PAUSED
    assert replay_command("p", rp, stop) == "resumed" and rp.status.state is ReplayState.PLAYING
    assert replay_command("s 1.0", rp, stop).startswith("at 1.0")
    assert replay_command("x max", rp, stop) == "speed max" and rp.speed == math.inf
    assert replay_command("x 1000", rp, stop).startswith("?")
    assert replay_command("q", rp, stop) == "quitting" and stop.is_set()


def test_seeking_is_not_counted_as_packet_loss(two_seconds):
    rp = Replay(two_seconds, speed=math.inf)
    it = rp.iter_measurements()
    for _ in range(30):
        next(it)
    rp.seek(1.5)
    list(rp.iter_measurements())
    assert rp.receiver.counters.seq_lost == 0
