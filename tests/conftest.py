import asyncio
import functools
import importlib.util
import os
import socket
import sys
from pathlib import Path
from types import ModuleType

import pytest

from groundstation.app.main import ONE_BLAS_THREAD

# the command line's BLAS threads in every test and every process a test starts (before numpy loads)
for _name, _value in ONE_BLAS_THREAD.items():
    os.environ.setdefault(_name, _value)

REPO = Path(__file__).resolve().parents[1]
#: the shared data (real logs, foreign flights): ../shared/data, or $GROUNDSTATION_DATA
DATA = Path(os.environ.get("GROUNDSTATION_DATA") or REPO.parent / "shared" / "data")
REAL = DATA / "real"
FOREIGN = DATA / "foreign"
FOREIGN2 = DATA / "foreign2"


@pytest.fixture(autouse=True)
def signing_state(tmp_path_factory, monkeypatch) -> Path:
    """Each test keeps its MAVLink signing timestamps in a folder of its own (drivers.mavlink.signing
    stores them across restarts, as the specification says): tests that share a key on parallel
    workers, or a rerun within the minute, must not read each other's."""
    folder = tmp_path_factory.mktemp("signing-state")
    monkeypatch.setenv("GROUNDSTATION_STATE", str(folder))
    return folder


def real_file(rel: str) -> Path:
    """A file of the shared real logs, or a visible skip when it is not there."""
    p = REAL / rel
    if not p.exists():
        pytest.skip(f"real data not available: {p} is absent (set GROUNDSTATION_DATA to the shared data folder)")
    return p


def foreign_file(rel: str) -> Path:
    """A file of the shared foreign flights (another generator's, with truth), or a visible skip."""
    p = FOREIGN / rel
    if not p.exists():
        pytest.skip(f"foreign flights not available: {p} is absent (set GROUNDSTATION_DATA to the shared data folder)")
    return p


def foreign2_file(rel: str) -> Path:
    """A file of the second foreign source (ArduPilot .bin and PX4 .ulg, with truth), or a visible skip."""
    p = FOREIGN2 / rel
    if not p.exists():
        pytest.skip(f"foreign flights not available: {p} is absent (set GROUNDSTATION_DATA to the shared data folder)")
    return p


def bench_module(name: str) -> ModuleType:
    """The script ``bench/<name>.py`` loaded as a module: bench/ is no package (its scripts run as
    commands), and the tests use what they compute (the plain filter, the foreign flights' variants)."""
    spec = importlib.util.spec_from_file_location(f"bench_{name}", REPO / "bench" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # as an import does: a dataclass there looks its module up
    spec.loader.exec_module(module)
    return module


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def async_test(timeout: float = 20.0):
    """Run an async test body on a fresh event loop, bounded in time."""

    def deco(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            return asyncio.run(asyncio.wait_for(fn(*args, **kwargs), timeout))

        return wrapper

    return deco


def pytest_collection_modifyitems(config, items):
    """The long tests first: on several workers (``-n``), handed out one at a time
    (``--maxschedchunk 1``), the short ones then fill the gaps, and no worker is left finishing a
    long test alone at the end. The order is the same on every worker, as xdist requires."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
