"""Command-line options shared by several commands: the dashboard's, MAVLink 2 signing."""

from __future__ import annotations

from drivers.mavlink.signing import signing_key


def key_of(args) -> bytes | None:
    """The signing key ``--signing`` names, or None (one-line ValueError for a bad key file)."""
    text = getattr(args, "signing", None)
    return signing_key(text) if text else None
