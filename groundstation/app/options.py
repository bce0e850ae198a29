"""Command-line options shared by several commands: the dashboard's, MAVLink 2 signing."""

from __future__ import annotations

import argparse

from drivers.mavlink.signing import signing_key


def add_web_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-web", action="store_true", help="headless: no dashboard")
    p.add_argument(
        "--host", default="127.0.0.1", help="dashboard address (default 127.0.0.1; another needs --allow-remote)"
    )
    p.add_argument("--port", type=int, default=8080, help="dashboard port (a free one if taken)")
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="serve the dashboard on a network address (--host): viewable from the network, "
        "control only with the session's token",
    )


def add_signing_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--signing",
        metavar="KEY",
        help="MAVLink 2 signing, required both ways: a key file (32 bytes or 64 hex digits) or a passphrase "
        "(SHA-256 of it, as MAVProxy's 'signing setup' makes the key)",
    )


def key_of(args) -> bytes | None:
    """The signing key ``--signing`` names, or None (one-line ValueError for a bad key file)."""
    text = getattr(args, "signing", None)
    return signing_key(text) if text else None
