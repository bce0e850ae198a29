"""MAVLink 2 message signing: the key, as MAVProxy's ``signing setup`` makes it, and the check of
incoming frames that the link's own framer (:mod:`.framing`, faster than pymavlink's parser)
needs, since pymavlink checks signatures only inside its own parser.

A signed frame carries link id, a 48-bit timestamp (10 us since 2015-01-01) and the first 6 bytes
of SHA-256(key + the frame up to them). With signing required, a frame is accepted as the
specification says (https://mavlink.io/en/guide/message_signing.html, "Accepting signed packets"):

* its signature matches, and only then does it count for anything (a frame with a wrong signature
  moves no timestamp: one forged frame stamped 2^48 - 10 had blocked the vehicle's valid stream);
* on a stream already seen (link id, system, component) its timestamp is later than the last one;
  on a new stream it is no more than a minute behind the local timestamp, which is the latest of
  the clock, every timestamp accepted, and the timestamp stored when this key was last used: a frame
  captured two minutes earlier, or an hour, or two years, is refused on a new link id too;
* it is not one of our own frames come back (our system and component): a reflection is a replay;
* unsigned frames are refused, whatever their message id, known or not, except RADIO_STATUS, which a
  radio modem cannot sign (MAVProxy accepts it too).

The local timestamp and every stream's last one are stored (:class:`SigningState`, a small JSON file
per key) as the specification recommends, so that frames captured before a restart are refused after
it; our own outgoing timestamps start after the stored one.
"""

from __future__ import annotations

import hashlib
import json
import os
import string
import time
from pathlib import Path

SIGNATURE_LEN = 13  # link id 1, timestamp 6, signature 6
EPOCH_2015 = 1_420_070_400  # the signing timestamp's zero [s, UNIX]
UNSIGNED_OK = {109}  # RADIO_STATUS


def signing_key(text: str) -> bytes:
    """A 32-byte key: from a file (32 raw bytes, or 64 hex digits), or SHA-256 of a passphrase."""
    p = Path(text)
    if p.is_file():
        raw = p.read_bytes()
        if len(raw) == 32:
            return raw
        s = raw.decode("ascii", "replace").strip()
        if len(s) == 64 and all(c in string.hexdigits for c in s):
            return bytes.fromhex(s)
        raise ValueError(f"{p}: not a signing key (32 bytes, or 64 hex digits)")
    if not text:
        raise ValueError("signing: an empty passphrase")
    return hashlib.sha256(text.encode()).digest()


def timestamp_now() -> int:
    """The signing timestamp for now (MAVProxy starts its stream there)."""
    return int((time.time() - EPOCH_2015) * 100_000)


#: a new stream's timestamp may be this far behind the local one (the specification's one minute)
NEW_STREAM_WINDOW = 60 * 100_000


def state_dir() -> Path:
    """Where signing state is kept: ``$GROUNDSTATION_STATE``, else ``$XDG_STATE_HOME/groundstation``,
    else ``~/.local/state/groundstation``."""
    explicit = os.environ.get("GROUNDSTATION_STATE")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "groundstation"


class SigningState:
    """The timestamps a key has seen, kept across restarts: the latest (``timestamp``) and each
    stream's. Stored at most every :data:`SAVE_EVERY` s and on :meth:`save`; a file that cannot be
    read or written leaves the state in memory (one line on ``warnings``, no traceback)."""

    SAVE_EVERY = 5.0
    MAX_STREAMS = 1024  #: streams remembered: a forger cycling link ids cannot grow the file

    def __init__(self, key: bytes, folder: Path | None = None, role: str = "gcs") -> None:
        """``role``: whose state it is (the ground station's, a simulated vehicle's): one key is
        shared by both ends, and each keeps the timestamps it has seen."""
        key_id = hashlib.sha256(b"groundstation-signing-state" + key).hexdigest()[:16]
        self.path = (folder or state_dir()) / f"signing-{role}-{key_id}.json"
        self.timestamp = 0
        self.streams: dict[tuple[int, int, int], int] = {}
        self.warning = ""
        self._saved_at = 0.0
        try:
            d = json.loads(self.path.read_text())
            self.timestamp = int(d.get("timestamp", 0))
            for k, v in d.get("streams", {}).items():
                link, sysid, compid = (int(x) for x in k.split(","))
                self.streams[(link, sysid, compid)] = int(v)
        except FileNotFoundError:  # the key's first use here: nothing stored, the clock alone
            self.timestamp, self.streams = 0, {}
        except (OSError, ValueError, TypeError, AttributeError) as e:
            self.warning = f"{self.path}: signing state not read ({e}); starting from the clock"

    def local(self) -> int:
        """The local timestamp: the clock, or later where a timestamp seen or stored is."""
        return max(timestamp_now(), self.timestamp)

    def saw(self, stream: tuple[int, int, int], ts: int) -> None:
        if stream not in self.streams and len(self.streams) >= self.MAX_STREAMS:
            del self.streams[min(self.streams, key=self.streams.__getitem__)]  # the stalest
        self.streams[stream] = ts
        self.timestamp = max(self.timestamp, ts)
        if time.monotonic() - self._saved_at > self.SAVE_EVERY:
            self.save()

    def save(self) -> None:
        self._saved_at = time.monotonic()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".tmp")
            streams = {f"{a},{b},{c}": v for (a, b, c), v in self.streams.items()}
            tmp.write_text(json.dumps({"timestamp": max(self.timestamp, timestamp_now()), "streams": streams}))
            tmp.replace(self.path)
        except OSError as e:
            self.warning = f"{self.path}: signing state not stored ({e.strerror or e})"


class SignatureCheck:
    """Accepts or refuses each MAVLink frame by its signature (see the module). ``own``: our system
    and component ids (their frames coming back are refused); ``state``: the timestamps kept across
    restarts (default: the key's file in :func:`state_dir`)."""

    def __init__(self, key: bytes, *, own: tuple[int, int] | None = None, state: SigningState | None = None) -> None:
        self.key = key
        self.own = own
        self.state = state if state is not None else SigningState(key)
        self.bad = 0  # signed with another key
        self.replayed = 0  # a timestamp not later than its stream's, or a new stream's too old
        self.reflected = 0  # our own frames, come back
        self.unsigned = 0  # not signed at all

    def accept(self, frame: bytes, msgid: int, sysid: int, compid: int) -> bool:
        signed = frame[0] == 0xFD and frame[2] & 0x01 and len(frame) > SIGNATURE_LEN
        if not signed:
            if msgid in UNSIGNED_OK:
                return True
            self.unsigned += 1
            return False
        if hashlib.sha256(self.key + frame[:-6]).digest()[:6] != frame[-6:]:
            self.bad += 1
            return False
        if self.own is not None and (sysid, compid) == self.own:
            self.reflected += 1
            return False
        stream = (frame[-SIGNATURE_LEN], sysid, compid)
        ts = int.from_bytes(frame[-12:-6], "little")
        last = self.state.streams.get(stream)
        if (last is not None and ts <= last) or (last is None and ts < self.state.local() - NEW_STREAM_WINDOW):
            self.replayed += 1
            return False
        self.state.saw(stream, ts)
        return True

    @property
    def refused(self) -> int:
        return self.bad + self.replayed + self.reflected + self.unsigned
