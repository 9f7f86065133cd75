"""An append-only, checksummed journal: the commit log of a run.

Each record is one line ``<crc32 as 8 hex digits> <json>\\n``. A record counts only when
its line is complete and its checksum matches; a line torn by a crash (kill -9, power
loss) fails the check and it and everything after it are discarded by :func:`read_journal`. The
writer appends and, when ``fsync`` is set, forces the line to stable storage before
returning, so "append returned" means "committed". See docs/decisions/0010.
"""

from __future__ import annotations

import json
import os
import zlib
from pathlib import Path
from typing import Any

__all__ = ["Journal", "read_journal"]


def _encode(record: dict[str, Any]) -> bytes:
    body = json.dumps(record, separators=(",", ":"), allow_nan=True).encode()
    return b"%08x " % zlib.crc32(body) + body + b"\n"


def read_journal(path: str | Path) -> tuple[list[dict[str, Any]], int]:
    """All intact records of a journal, and the byte length of the intact prefix."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return [], 0
    records: list[dict[str, Any]] = []
    good = 0
    pos = 0
    while pos < len(data):
        end = data.find(b"\n", pos)
        if end < 0:
            break
        line = data[pos:end]
        if len(line) < 10 or line[8:9] != b" ":
            break
        body = line[9:]
        try:
            crc = int(line[:8], 16)
        except ValueError:
            break
        if zlib.crc32(body) != crc:
            break
        try:
            records.append(json.loads(body))
        except ValueError:
            break
        pos = end + 1
        good = pos
    return records, good


class Journal:
    """Append records to ``path``; the file is truncated to its intact prefix on open."""

    def __init__(self, path: str | Path, *, fsync: bool = True) -> None:
        self.path = Path(path)
        self.fsync = fsync
        _, good = read_journal(self.path)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            os.ftruncate(fd, good)
            os.lseek(fd, good, os.SEEK_SET)
        except BaseException:
            os.close(fd)
            raise
        self._fd: int | None = fd

    def append(self, record: dict[str, Any]) -> None:
        """Write one record; when this returns it survives a process kill (and, with
        ``fsync``, an OS crash)."""
        if self._fd is None:
            raise ValueError("journal is closed")
        data = _encode(record)
        view = memoryview(data)
        start = os.lseek(self._fd, 0, os.SEEK_CUR)
        try:
            while view:
                n = os.write(self._fd, view)
                view = view[n:]
            if self.fsync:
                os.fsync(self._fd)
        except OSError:
            # Never leave a torn line behind a failed write (ENOSPC, EIO): the next
            # append would otherwise follow garbage that the reader stops at.
            try:
                os.ftruncate(self._fd, start)
                os.lseek(self._fd, start, os.SEEK_SET)
            except OSError:
                pass
            raise

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
