"""Command-line options shared by the commands that serve a dashboard."""

from __future__ import annotations

import argparse


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
