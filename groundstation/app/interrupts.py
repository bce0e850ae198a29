"""Whether an exception is Ctrl-C; imports nothing, so the entry module can use it without cost."""

from __future__ import annotations


def is_interrupt(e: BaseException) -> bool:
    """Whether ``e`` is Ctrl-C: a KeyboardInterrupt, or one raised inside a C extension's callback and
    wrapped there (numba loading a cached kernel on its first call turns it into a SystemError whose
    cause is the KeyboardInterrupt)."""
    seen: set[int] = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__  # type: ignore[assignment]
    return False
