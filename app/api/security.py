"""Password hashing (stdlib scrypt), login tokens and the first-run admin account."""

from __future__ import annotations

import base64
import hashlib
import hmac
import logging
import secrets
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
