# SPDX-License-Identifier: BSD-3-Clause
"""The panel's web app (Starlette, served over HTTPS by uvicorn): one page, its JSON, three
actions, and a password login.

Routes::

    GET  /                    the panel (login page, 401, without a valid session)
    POST /login               form field "password" -> session cookie, 303 to /
    POST /logout
    GET  /api/state?have=N    the live state (JSON; the range image only when newer than N)
    POST /api/control/CMD     start | stop | mark, JSON body {"label": "..."}
    GET  /static/...          the page's CSS and JavaScript (shipped in the package)

Sessions: a random token in an HttpOnly, Secure, SameSite=Strict cookie, kept in memory
(a panel restart logs everyone out). Actions need a JSON body as well, so a cross-site form
cannot send one. Wrong passwords are answered after a second's wait.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import secrets
import time
from importlib import resources
from urllib.parse import parse_qs

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, RedirectResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from tripod_shared import topics

from ..client import ClientError, ControlRefused
from .live import LiveState

log = logging.getLogger(__name__)

COOKIE = "tripod_panel"
MAX_SESSIONS = 64
_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; "
    "frame-ancestors 'none'; form-action 'self'; base-uri 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


def _static_dir() -> str:
    return str(resources.files("tripod_daemon.panel").joinpath("static"))


def _page(name: str) -> str:
    return resources.files("tripod_daemon.panel").joinpath("static", name).read_text("utf-8")


class Sessions:
    """Login tokens -> expiry (host_monotonic [s])."""

    def __init__(self, lifetime_s: float):
        self.lifetime_s = lifetime_s
        self._tokens: dict[str, float] = {}

    def new(self) -> str:
        now = time.monotonic()
        self._tokens = {t: e for t, e in self._tokens.items() if e > now}
        while len(self._tokens) >= MAX_SESSIONS:  # the oldest login goes first
            self._tokens.pop(min(self._tokens, key=self._tokens.get))
        token = secrets.token_urlsafe(32)
        self._tokens[token] = now + self.lifetime_s
        return token

    def valid(self, token: str | None) -> bool:
        if not token:
            return False
        exp = self._tokens.get(token)
        if exp is None:
            return False
        if exp <= time.monotonic():
            del self._tokens[token]
            return False
        return True

    def drop(self, token: str | None) -> None:
        self._tokens.pop(token or "", None)


def create_app(live: LiveState, password: str, session_hours: float = 12.0) -> Starlette:
    """The ASGI app. ``live`` is started and closed with the app (lifespan)."""
    sessions = Sessions(session_hours * 3600.0)
    index_html = _page("index.html").replace("{{device_id}}", live.opts.device_id)
    login_html = _page("login.html").replace("{{device_id}}", live.opts.device_id)
    login_lock = asyncio.Lock()

    def authed(request: Request) -> bool:
        return sessions.valid(request.cookies.get(COOKIE))

    def login_page(message: str = "", status: int = 401) -> HTMLResponse:
        body = login_html.replace("{{message}}", message)
        return HTMLResponse(body, status_code=status, headers=_HEADERS)

    async def index(request: Request) -> Response:
        if not authed(request):
            return login_page()
        return HTMLResponse(index_html, headers=_HEADERS)

    async def login(request: Request) -> Response:
        body = await request.body()
        if len(body) > 4096:
            return login_page("Too long.", 413)
        form = parse_qs(body.decode("utf-8", "replace"))
        given = (form.get("password") or [""])[0]
        async with login_lock:  # one guess at a time, each wrong one costs a second
            if not hmac.compare_digest(given.encode(), password.encode()):
                log.warning("panel: wrong password from %s",
                            request.client.host if request.client else "?")
                await asyncio.sleep(1.0)
                return login_page("Wrong password.")
        resp = RedirectResponse("/", status_code=303, headers=_HEADERS)
        resp.set_cookie(COOKIE, sessions.new(), max_age=int(session_hours * 3600), path="/",
                        secure=True, httponly=True, samesite="strict")
        log.info("panel: login from %s", request.client.host if request.client else "?")
        return resp

    async def logout(request: Request) -> Response:
        sessions.drop(request.cookies.get(COOKIE))
        resp = RedirectResponse("/", status_code=303, headers=_HEADERS)
        resp.delete_cookie(COOKIE, path="/")
        return resp

    def refused() -> JSONResponse:
        return JSONResponse({"ok": False, "error": "log in first"}, status_code=401,
                            headers=_HEADERS)

    async def state(request: Request) -> Response:
        if not authed(request):
            return refused()
        try:
            have = int(request.query_params.get("have", "-1"))
        except ValueError:
            have = -1
        return JSONResponse(live.snapshot(have), headers=_HEADERS)

    async def do_control(request: Request) -> Response:
        if not authed(request):
            return refused()
        command = request.path_params["command"]
        if command not in topics.CONTROL_COMMANDS:
            return JSONResponse({"ok": False, "error": f"unknown command {command!r}"},
                                status_code=404, headers=_HEADERS)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return JSONResponse({"ok": False, "error": "expected a JSON body"},
                                status_code=415, headers=_HEADERS)
        body = await request.body()
        try:
            data = json.loads(body) if body else {}
            label = str(data.get("label", "")) if command == "mark" else ""
        except (ValueError, AttributeError):
            return JSONResponse({"ok": False, "error": "bad JSON"}, status_code=400,
                                headers=_HEADERS)
        try:
            reply = await run_in_threadpool(live.control, command, label)
        except ControlRefused as exc:
            return JSONResponse({"ok": False, "error": str(exc)}, status_code=409,
                                headers=_HEADERS)
        except ClientError as exc:
            return JSONResponse({"ok": False, "error": str(exc)}, status_code=503,
                                headers=_HEADERS)
        log.info("panel: %s%s -> %s", command, f" {label!r}" if label else "", reply)
        return JSONResponse(reply, headers=_HEADERS)

    @contextlib.asynccontextmanager
    async def lifespan(_app):
        live.start()
        try:
            yield
        finally:
            await run_in_threadpool(live.close)

    return Starlette(
        routes=[
            Route("/", index),
            Route("/login", login, methods=["POST"]),
            Route("/logout", logout, methods=["POST"]),
            Route("/api/state", state),
            Route("/api/control/{command}", do_control, methods=["POST"]),
            Mount("/static", StaticFiles(directory=_static_dir()), name="static"),
        ],
        lifespan=lifespan,
    )
