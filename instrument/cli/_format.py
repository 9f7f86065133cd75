"""Small text formatting shared by the subcommands (no heavy imports)."""

from __future__ import annotations

__all__ = ["fmt_s"]


def fmt_s(seconds: float) -> str:
    """A duration in words a console line can hold: '2.7s', '26s', '3m05s', '1h02m'."""
    seconds = max(0.0, float(seconds))
    if seconds < 10:  # short acquisitions would otherwise all read "0s"
        return f"{seconds:.2g}s" if seconds >= 0.01 or seconds == 0 else "<0.01s"
    if seconds < 60:
        return f"{seconds:.0f}s"
    if seconds < 3600:
        return f"{int(seconds // 60)}m{int(seconds % 60):02d}s"
    return f"{int(seconds // 3600)}h{int(seconds % 3600 // 60):02d}m"
