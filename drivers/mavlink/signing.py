"""MAVLink 2 message signing: the key, as MAVProxy's ``signing setup`` makes it, and the check of
incoming frames that the link's own framer (:mod:`.framing`, faster than pymavlink's parser)
needs, since pymavlink checks signatures only inside its own parser.

A signed frame carries link id, a 48-bit timestamp (10 us since 2015-01-01) and the first 6 bytes
of SHA-256(key + the frame up to them). With signing required, a frame is accepted when its
signature matches and its timestamp is later than the last one of its stream (link, system,
component): replays are refused. Unsigned frames are refused, except RADIO_STATUS, which a radio
modem cannot sign (MAVProxy accepts it too).
"""

from __future__ import annotations

import hashlib
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


class SignatureCheck:
    """Accepts or refuses each MAVLink frame by its signature (see the module)."""

    def __init__(self, key: bytes) -> None:
        self.key = key
        self._last: dict[tuple[int, int, int], int] = {}
        self.bad = 0  # signed with another key, or replayed
        self.unsigned = 0  # not signed at all

    def accept(self, frame: bytes, msgid: int, sysid: int, compid: int) -> bool:
        signed = frame[0] == 0xFD and frame[2] & 0x01 and len(frame) > SIGNATURE_LEN
        if not signed:
            if msgid in UNSIGNED_OK:
                return True
            self.unsigned += 1
            return False
        sig = frame[-6:]
        if hashlib.sha256(self.key + frame[:-6]).digest()[:6] != sig:
            self.bad += 1
            return False
        link_id = frame[-SIGNATURE_LEN]
        ts = int.from_bytes(frame[-12:-6], "little")
        key = (link_id, sysid, compid)
        if ts <= self._last.get(key, -1):
            self.bad += 1
            return False
        self._last[key] = ts
        return True
