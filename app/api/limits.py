"""Request size limits of the REST API.

Every router uses :class:`BoundedRoute` (``APIRouter(..., route_class=BoundedRoute)``): a
request body larger than the route's ``max_body_size`` — :data:`JSON_BODY_MAX` unless the
route declares its own, as the uploads do — is refused with HTTP 413 and a message that
names the limit (or the route's own words for it: :func:`refused_with`, as the reference
uploads say one message of a file too large, whichever check finds it). A declared
``Content-Length`` is checked before anything is read; a body without one is counted while
it is read, so neither a huge JSON body nor an over-size upload
is held in memory or spooled to disk in full. An upload (a route with a larger limit
that requires a login) is refused with 401 before its body is read, so an anonymous client
cannot make the server spool hundreds of MB.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from fastapi import HTTPException, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from starlette.types import Message

from app.api.deps import get_current_user

#: Largest JSON body of any route without its own limit: the largest real one (64 sensor
#: poses, or 4000-character notes) is a few kB.
JSON_BODY_MAX = 1024 * 1024


def size_words(n: int, *, round_up: bool = False) -> str:
    """A size as the messages say it: whole MB from 1 MB ("200 MB"), whole KB below
    ("4 KB"). ``round_up`` for a size said to be over a limit, so that 256.3 MB over a
    256 MB limit reads "257 MB", not "256 MB, more than the 256 MB"."""
    unit, name = (2**20, "MB") if n >= 2**20 else (1024, "KB")
    whole = -(-n // unit) if round_up else max(1, round(n / unit))
    return f"{whole} {name}"


def too_large(limit: int) -> HTTPException:
    """HTTP 413 naming the limit."""
    return HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                         f"the request is larger than this route accepts "
                         f"({size_words(limit)}); send a smaller file or fewer values")


_Endpoint = TypeVar("_Endpoint", bound=Callable[..., Any])


def refused_with(refusal: Callable[[], HTTPException]) -> Callable[[_Endpoint], _Endpoint]:
    """Decorator of an endpoint, under its ``@router.post(...)``: a request body over the
    route's ``max_body_size`` is refused with ``refusal()`` instead of :func:`too_large`'s
    general words — the words the endpoint says of a file over its own limit, so that a
    file too large is refused alike whether its request declares the size, its streamed
    body passes the limit or the endpoint counts the file."""
    def mark(endpoint: _Endpoint) -> _Endpoint:
        endpoint.body_refusal = refusal  # type: ignore[attr-defined]
        return endpoint
    return mark


def _needs_login(dependant: Dependant) -> bool:
    return dependant.call is get_current_user or any(
        _needs_login(d) for d in dependant.dependencies)


def _check_login(request: Request) -> None:
    """HTTP 401 unless the request carries a valid login (as ``CurrentUser`` checks)."""
    with request.app.state.db_sessions() as db:
        get_current_user(request, db)


class BoundedRoute(APIRoute):
    """An ``APIRoute`` whose request body is bounded by ``max_body_size`` (default
    :data:`JSON_BODY_MAX`), refused with a readable HTTP 413."""

    def __init__(self, path: str, endpoint: Callable[..., Any], *,
                 max_body_size: int | None = None, **kwargs: Any) -> None:
        #: Largest accepted request body (bytes).
        self.body_limit = JSON_BODY_MAX if max_body_size is None else max_body_size
        #: The endpoint's words for a body over the limit (:func:`refused_with`), if any.
        self.body_refusal: Callable[[], HTTPException] | None = getattr(
            endpoint, "body_refusal", None)
        # Not handed to FastAPI: its own limiter would answer a bare "Content Too Large"
        # (plain text when Content-Length is over) before the handler below could say more.
        super().__init__(path, endpoint, **kwargs)

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        login_first = self.body_limit > JSON_BODY_MAX and _needs_login(self.dependant)

        async def bounded(request: Request) -> Response:
            limit = self.body_limit

            def refused() -> HTTPException:
                return self.body_refusal() if self.body_refusal else too_large(limit)

            declared = request.headers.get("content-length", "")
            if declared.isdigit() and int(declared) > limit:
                raise refused()
            if login_first:
                await run_in_threadpool(_check_login, request)
            receive = request.receive
            total = 0

            async def counted() -> Message:
                nonlocal total
                msg = await receive()
                if msg["type"] == "http.request":
                    total += len(msg.get("body", b""))
                    if total > limit:
                        raise refused()
                return msg

            return await handler(Request(request.scope, counted))

        return bounded
