"""Shared builders for tests: real pymavlink frames and tlogs, and processes a test runs."""

import asyncio
import contextlib
import struct
import subprocess
import sys
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink


def imu_frames(n: int, *, sysid=1, t0_ms=1000, dt_ms=10, mavlink1=False, enc=None):
    """n SCALED_IMU frames (level vehicle, z reads -1 g) with their vehicle times."""
    enc = enc or mavlink.MAVLink(None, sysid, 1)
    out = []
    for i in range(n):
        msg = mavlink.MAVLink_scaled_imu_message(t0_ms + i * dt_ms, i % 100, 0, -1000, 0, 0, 0, 0, 0, 0)
        out.append(bytes(msg.pack(enc, force_mavlink1=mavlink1)))
        enc.seq = (enc.seq + 1) % 256
    return out


def write_tlog(path: Path, frames, t0=1_700_000_000.0, dt=0.01, gap_after=None, gap=0.0):
    """Write frames as a tlog by hand (independent of our writer)."""
    with open(path, "wb") as f:
        t = t0
        for i, fr in enumerate(frames):
            f.write(struct.pack(">Q", int(t * 1e6)) + fr)
            t += dt
            if gap_after is not None and i == gap_after:
                t += gap
    return path


@contextlib.contextmanager
def running(args, **popen):
    """A process the test starts, stopped when the block ends, also when the test fails
    (terminated, then killed if it does not end within 10 s)."""
    popen.setdefault("stdout", subprocess.DEVNULL)
    popen.setdefault("stderr", subprocess.DEVNULL)
    p = subprocess.Popen([str(a) for a in args], **popen)
    try:
        yield p
    finally:
        p.terminate()
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def simulated_vehicle(port: int, *args: str):
    """``groundstation sim`` sending to 127.0.0.1:``port`` (more options in ``args``), as :func:`running`."""
    return running([sys.executable, "-m", "groundstation", "sim", "--udp", f"127.0.0.1:{port}", *args])


async def until(cond, timeout: float, what: str) -> None:
    """Wait for a condition a link, a vehicle or a panel reaches (checked as the loop turns)."""
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise AssertionError(f"not within {timeout} s: {what}")
        await asyncio.sleep(0.02)
