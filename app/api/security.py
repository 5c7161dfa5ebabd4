"""Password hashing (stdlib scrypt), login tokens and the first-run admin account."""

from __future__ import annotations

import base64
import hashlib
import hmac
import logging
import secrets
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from app.db.models import LoginSession, User

log = logging.getLogger("gaitrig.auth")

# scrypt cost: 16 MiB of memory and ~50 ms per hash, OWASP's minimum recommendation.
_N, _R, _P = 2**14, 8, 1


def hash_password(password: str) -> str:
    """``scrypt$N$r$p$salt$hash`` with a fresh 16-byte salt."""
    salt = secrets.token_bytes(16)
    h = hashlib.scrypt(password.encode(), salt=salt, n=_N, r=_R, p=_P, dklen=32)
    b64 = base64.b64encode
    return f"scrypt${_N}${_R}${_P}${b64(salt).decode()}${b64(h).decode()}"


def verify_password(password: str, stored: str) -> bool:
    """Constant-time check of ``password`` against :func:`hash_password`'s output."""
    try:
        kind, n, r, p, salt, h = stored.split("$")
        if kind != "scrypt":
            return False
        got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r),
                             p=int(p), dklen=32)
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, base64.b64decode(h))


def _token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def ensure_admin(db: Session, username: str, password: str | None) -> str | None:
    """Create the admin account when there is no user yet.

    Returns:
        The password when it was generated here (the caller prints it once), else None.
    """
    if db.scalar(select(User.id).limit(1)) is not None:
        return None
    generated = None
    if not password:
        password = generated = secrets.token_urlsafe(12)
    db.add(User(username=username, password_hash=hash_password(password), is_admin=True))
    db.commit()
    log.info("created admin account %r", username)
    return generated


def login(db: Session, username: str, password: str, hours: float) -> tuple[str, datetime] | None:
    """Check credentials; returns a new ``(token, expiry)`` or None."""
    user = db.scalar(select(User).where(User.username == username))
    if user is None:
        hash_password(password)  # same cost whether or not the user exists
        return None
    if not verify_password(password, user.password_hash):
        return None
    token = secrets.token_urlsafe(32)
    expires = datetime.now(UTC) + timedelta(hours=hours)
    db.add(LoginSession(token_sha256=_token_hash(token), user_id=user.id, expires_at=expires))
    db.execute(delete(LoginSession).where(LoginSession.expires_at < datetime.now(UTC)))
    db.commit()
    return token, expires


def user_for_token(db: Session, token: str) -> User | None:
    """The user of a valid, unexpired token."""
    sess = db.scalar(select(LoginSession).where(LoginSession.token_sha256 == _token_hash(token)))
    if sess is None:
        return None
    exp = sess.expires_at if sess.expires_at.tzinfo else sess.expires_at.replace(tzinfo=UTC)
    if exp < datetime.now(UTC):
        return None
    return sess.user


def logout(db: Session, token: str) -> None:
    """Invalidate one token."""
    db.execute(delete(LoginSession).where(LoginSession.token_sha256 == _token_hash(token)))
    db.commit()


@dataclass
class LoginThrottle:
    """Failed logins per (user name, client address): after ``max_failures`` within
    ``window_s`` that pair is refused until the oldest of them is ``window_s`` old.

    Each guess already costs ~50 ms of scrypt; this bounds a password guesser to a handful
    of tries per window on one address without locking the user out from elsewhere (the
    lab's own workstation). In memory: a server restart forgets it, as it should.
    """

    max_failures: int = 5
    window_s: float = 300.0
    _failures: dict[tuple[str, str], list[float]] = field(default_factory=dict)

    def _recent(self, key: tuple[str, str], now: float) -> list[float]:
        kept = [t for t in self._failures.get(key, []) if now - t < self.window_s]
        if kept:
            self._failures[key] = kept
        else:
            self._failures.pop(key, None)
        return kept

    def retry_after(self, username: str, client: str, now: float | None = None) -> float:
        """Seconds until this pair may try again (0: now)."""
        now = time.monotonic() if now is None else now
        recent = self._recent((username.lower(), client), now)
        if len(recent) < self.max_failures:
            return 0.0
        return max(0.0, recent[-self.max_failures] + self.window_s - now)

    def failed(self, username: str, client: str, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        key = (username.lower(), client)
        self._failures[key] = [*self._recent(key, now), now][-self.max_failures:]
        if len(self._failures) > 10_000:  # bounded memory under a spray of names
            self._failures.pop(next(iter(self._failures)))

    def succeeded(self, username: str, client: str) -> None:
        self._failures.pop((username.lower(), client), None)
