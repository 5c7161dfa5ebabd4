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

from app.db.models import LoginSession, PasswordChangeDue, User

log = logging.getLogger("gaitrig.auth")

#: scrypt's cost as log2(N), with r = 8, p = 1: 17 is OWASP's recommendation (128 MiB and
#: a few hundred ms per hash); the setting ``password_hash_cost`` chooses it, and stored
#: hashes carry their own N, so raising it leaves older hashes valid (they are re-hashed
#: at the next login).
DEFAULT_HASH_COST = 17
_R, _P = 8, 1


def _maxmem(n: int, r: int) -> int:
    # scrypt needs 128·N·r bytes; hashlib refuses above its 32 MiB default unless told
    return 128 * n * r + (1 << 20)


def hash_password(password: str, cost: int = DEFAULT_HASH_COST) -> str:
    """``scrypt$N$r$p$salt$hash`` with a fresh 16-byte salt and N = 2**cost."""
    n = 2 ** int(cost)
    salt = secrets.token_bytes(16)
    h = hashlib.scrypt(password.encode(), salt=salt, n=n, r=_R, p=_P, dklen=32,
                       maxmem=_maxmem(n, _R))
    b64 = base64.b64encode
    return f"scrypt${n}${_R}${_P}${b64(salt).decode()}${b64(h).decode()}"


def hash_cost(stored: str) -> int | None:
    """log2(N) of a stored hash (None when it is not one of ours)."""
    try:
        kind, n, *_ = stored.split("$")
        return int(n).bit_length() - 1 if kind == "scrypt" and int(n) > 1 else None
    except ValueError:
        return None


def verify_password(password: str, stored: str) -> bool:
    """Constant-time check of ``password`` against :func:`hash_password`'s output."""
    try:
        kind, n, r, p, salt, h = stored.split("$")
        if kind != "scrypt" or not 1 < int(n) <= 2**20 or not 0 < int(r) <= 16:
            return False
        got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r),
                             p=int(p), dklen=32, maxmem=_maxmem(int(n), int(r)))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, base64.b64decode(h))


def _token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def ensure_admin(db: Session, username: str, password: str | None,
                 cost: int = DEFAULT_HASH_COST) -> str | None:
    """Create the admin account when there is no user yet (password hashed at ``cost``).

    Returns:
        The password when it was generated here (the caller prints it once), else None.
    """
    if db.scalar(select(User.id).limit(1)) is not None:
        return None
    generated = None
    if not password:
        password = generated = secrets.token_urlsafe(12)
    admin = User(username=username, password_hash=hash_password(password, cost),
                 is_admin=True)
    db.add(admin)
    if generated:  # printed in a log: the console asks its owner to change it
        db.flush()
        db.add(PasswordChangeDue(user_id=admin.id, reason="generated"))
    db.commit()
    log.info("created admin account %r", username)
    return generated


#: Shortest password accepted for a new password (NIST SP 800-63B asks for ≥ 8; a
#: clinic's shared workstation account deserves more).
MIN_PASSWORD_LENGTH = 12


def password_problem(password: str, username: str) -> str | None:
    """Why ``password`` is not acceptable for ``username`` (a sentence), or None.

    The policy of NIST SP 800-63B: a minimum length and no obviously guessable value; no
    composition rules (they make passwords harder to remember, not to guess).
    """
    if len(password) < MIN_PASSWORD_LENGTH:
        return (f"the password must have at least {MIN_PASSWORD_LENGTH} characters "
                f"(it has {len(password)}); a few words make a good one")
    if len(password) > 256:
        return "the password must have at most 256 characters"
    if len(set(password)) < 4:
        return "the password repeats too few characters; choose a less predictable one"
    if username and username.lower() in password.lower():
        return "the password must not contain the user name"
    return None


def login(db: Session, username: str, password: str, hours: float,
          idle_s: float | None = None, cost: int = DEFAULT_HASH_COST
          ) -> tuple[str, datetime] | None:
    """Check credentials; returns a new ``(token, expiry)`` or None.

    A password stored at a lower cost than ``cost`` is re-hashed at ``cost`` on success.

    The expiry is the sooner of ``hours`` from now and, with ``idle_s``, the idle timeout
    (pushed on by every authenticated request, see :func:`user_for_token`).
    """
    user = db.scalar(select(User).where(User.username == username))
    if user is None:
        hash_password(password, cost)  # same cost whether or not the user exists
        return None
    if not verify_password(password, user.password_hash):
        return None
    if (hash_cost(user.password_hash) or 0) < cost:
        user.password_hash = hash_password(password, cost)
    token = secrets.token_urlsafe(32)
    now = datetime.now(UTC)
    expires = now + timedelta(seconds=min(hours * 3600, idle_s if idle_s else hours * 3600))
    db.add(LoginSession(token_sha256=_token_hash(token), user_id=user.id, created_at=now,
                        expires_at=expires))
    db.execute(delete(LoginSession).where(LoginSession.expires_at < now))
    db.commit()
    return token, expires


def _aware(t: datetime) -> datetime:
    return t if t.tzinfo else t.replace(tzinfo=UTC)


#: The idle expiry is written back at most this often per login (not on every request).
_TOUCH_S = 60.0


def user_for_token(db: Session, token: str, idle_s: float | None = None,
                   lifetime_s: float | None = None) -> User | None:
    """The user of a valid, unexpired token.

    With ``idle_s`` (the idle timeout) and ``lifetime_s`` (the absolute lifetime), this
    request counts as activity: the login's expiry moves to ``idle_s`` from now, never
    past ``lifetime_s`` after the login (written at most once a minute).
    """
    sess = db.scalar(select(LoginSession).where(LoginSession.token_sha256 == _token_hash(token)))
    if sess is None:
        return None
    now = datetime.now(UTC)
    exp = _aware(sess.expires_at)
    if exp < now:
        return None
    if idle_s and lifetime_s:
        new = min(_aware(sess.created_at) + timedelta(seconds=lifetime_s),
                  now + timedelta(seconds=idle_s))
        if (new - exp).total_seconds() > _TOUCH_S:
            sess.expires_at = new
            db.commit()
    return sess.user


def logout(db: Session, token: str) -> None:
    """Invalidate one token."""
    db.execute(delete(LoginSession).where(LoginSession.token_sha256 == _token_hash(token)))
    db.commit()


def change_password(db: Session, user: User, new_password: str, keep_token: str | None,
                    cost: int = DEFAULT_HASH_COST) -> int:
    """Set ``user``'s password (hashed at ``cost``) and end every other login of theirs.

    Returns:
        How many other logins were ended.
    """
    user.password_hash = hash_password(new_password, cost)
    q = delete(LoginSession).where(LoginSession.user_id == user.id)
    if keep_token:
        q = q.where(LoginSession.token_sha256 != _token_hash(keep_token))
    ended = int(getattr(db.execute(q), "rowcount", 0) or 0)
    db.commit()
    return ended


@dataclass
class LoginThrottle:
    """Failed logins per (user name, client address), and per address over all names.

    After ``max_failures`` within ``window_s`` for one name from one address, that pair is
    refused until the oldest of them is ``window_s`` old; after ``ADDRESS_FACTOR`` times as
    many from one address under any names (a password spray over user names), the address
    is. Each guess already costs ~50 ms of scrypt; this bounds a guesser to a handful of
    tries per window on one address without locking the user out from elsewhere (the
    lab's own workstation). In memory: a server restart forgets it, as it should.
    """

    max_failures: int = 5
    window_s: float = 300.0
    _failures: dict[tuple[str, str], list[float]] = field(default_factory=dict)

    #: Failures from one address under any names, as a multiple of ``max_failures``.
    ADDRESS_FACTOR = 4
    _ANY = "\x00any"  # not a user name (names are typed text)

    def _recent(self, key: tuple[str, str], now: float) -> list[float]:
        kept = [t for t in self._failures.get(key, []) if now - t < self.window_s]
        if kept:
            self._failures[key] = kept
        else:
            self._failures.pop(key, None)
        return kept

    def _limits(self, username: str, client: str) -> list[tuple[tuple[str, str], int]]:
        return [((username.lower(), client), self.max_failures),
                ((self._ANY, client), self.max_failures * self.ADDRESS_FACTOR)]

    def retry_after(self, username: str, client: str, now: float | None = None) -> float:
        """Seconds until this pair may try again (0: now)."""
        now = time.monotonic() if now is None else now
        wait = 0.0
        for key, limit in self._limits(username, client):
            recent = self._recent(key, now)
            if len(recent) >= limit:
                wait = max(wait, recent[-limit] + self.window_s - now)
        return max(0.0, wait)

    def failed(self, username: str, client: str, now: float | None = None) -> bool:
        """Count a failed login.

        Returns:
            True when this failure starts a pause (the caller records that in the audit
            trail).
        """
        now = time.monotonic() if now is None else now
        for key, limit in self._limits(username, client):
            self._failures[key] = [*self._recent(key, now), now][-limit:]
        while len(self._failures) > 10_000:  # bounded memory under a spray of names
            self._failures.pop(next(iter(self._failures)))
        return self.retry_after(username, client, now) > 0

    def succeeded(self, username: str, client: str) -> None:
        self._failures.pop((username.lower(), client), None)
