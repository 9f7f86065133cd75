"""API keys: random tokens given once to their holder; only their SHA-256 is stored.

A key is ``sl_`` + 43 URL-safe characters (32 random bytes from :mod:`secrets`). The
server keeps the hex SHA-256 of the token, so a copy of ``server.sqlite`` does not give
access; a presented token is hashed and its digest compared with each stored one by
:func:`hmac.compare_digest` (constant time: the comparison does not tell how many leading
characters matched). A plain hash suffices, unlike for passwords, because the token has
256 bits of entropy: there is nothing to guess by trying hashes.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import time
from dataclasses import dataclass

from instrument.protocol import ROLES
from instrument.server.db import ServerDB

__all__ = ["ApiKey", "KeyStore", "digest"]

TOKEN_PREFIX = "sl_"


def digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


@dataclass(frozen=True)
class ApiKey:
    id: int
    name: str
    role: str
    created: float
    expires: float | None
    revoked: float | None

    def valid(self, now: float) -> bool:
        return self.revoked is None and (self.expires is None or now < self.expires)

    def state(self, now: float) -> str:
        if self.revoked is not None:
            return "revoked"
        if self.expires is not None and now >= self.expires:
            return "expired"
        return "valid"


class KeyStore:
    """The keys in a :class:`ServerDB`."""

    def __init__(self, db: ServerDB) -> None:
        self.db = db

    def add(self, name: str, role: str, *, expires: float | None = None) -> tuple[ApiKey, str]:
        """Make a key; return it and its token (shown once, never stored).

        Raises
        ------
        ValueError
            Unknown role, empty name, or an expiry in the past.
        """
        if role not in ROLES:
            raise ValueError(f"--role must be one of {', '.join(ROLES)}, got {role!r}")
        name = name.strip()
        if not name:
            raise ValueError("--name must name who holds the key")
        now = time.time()
        if expires is not None and expires <= now:
            raise ValueError("--expires is in the past")
        token = TOKEN_PREFIX + secrets.token_urlsafe(32)
        with self.db.transaction() as db:
            cur = db.execute("INSERT INTO keys (name, role, digest, created, expires) "
                             "VALUES (?,?,?,?,?)", (name, role, digest(token), now, expires))
            key_id = int(cur.lastrowid)  # type: ignore[arg-type]  # an INSERT sets it
        return ApiKey(key_id, name, role, now, expires, None), token

    def list(self) -> list[ApiKey]:
        return [ApiKey(*r) for r in self.db.query(
            "SELECT id, name, role, created, expires, revoked FROM keys ORDER BY id")]

    def any_valid(self) -> bool:
        now = time.time()
        return any(k.valid(now) for k in self.list())

    def revoke(self, key_id: int) -> ApiKey:
        """Revoke a key by id (idempotent); ``KeyError`` when there is none."""
        with self.db.transaction() as db:
            n = db.execute("UPDATE keys SET revoked = ? WHERE id = ? AND revoked IS NULL",
                           (time.time(), key_id)).rowcount
            row = db.execute("SELECT id, name, role, created, expires, revoked FROM keys "
                             "WHERE id = ?", (key_id,)).fetchone()
        if row is None:
            raise KeyError(f"no key with id {key_id}")
        del n
        return ApiKey(*row)

    def check(self, token: str) -> ApiKey | None:
        """The valid key whose token this is, or ``None``."""
        want = digest(token)
        now = time.time()
        found = None
        for row in self.db.query("SELECT id, name, role, created, expires, revoked, digest "
                                 "FROM keys"):
            # every row is compared, so the time taken does not say which one matched
            if hmac.compare_digest(row[6], want):
                found = ApiKey(*row[:6])
        return found if found is not None and found.valid(now) else None
