"""Counted skips, as one phrase for status lines, panels and reports."""

from __future__ import annotations

from collections.abc import Mapping


def counted(counts: Mapping[str, int]) -> str:
    """Counted skips as one phrase, most first: ``564 range_out_of_bounds, 12 not_finite``."""
    return ", ".join(f"{n} {why}" for why, n in sorted(counts.items(), key=lambda kv: -kv[1]) if n)
