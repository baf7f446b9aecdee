"""The operator web UI: a FastAPI app around a running :class:`~armvision.runtime.system.System`.

One page (``static/``: plain HTML, JS and CSS, no build step) talks to these endpoints:

- ``GET /``: the page; ``GET /static/...``: its script and style.
- ``WS /ws/state``: the state as JSON (:func:`state_payload`), ``ui.state_hz`` times a second.
- ``GET /api/state``: the same, once.
- ``GET /stream.mjpg?view=color|depth``: MJPEG of the annotated colour image or of the
  colourised depth, at most ``ui.video_fps``; ``GET /api/frame.jpg?view=...``: one JPEG.
- ``POST /api/actions/{name}`` (JSON body of the action's parameters, ``Content-Type:
  application/json``): start a task in the background, 202 with its id; 409 while another task
  runs (press Stop first).
- ``POST /api/stop``: Stop, always accepted whatever its body or content type: the arm halts
  where it is, the task ends.
- ``POST /api/detectors/{name}`` ``{"enabled": bool}`` (JSON): switch tag, object or liquid
  detection.
- ``POST /api/recording/start`` and ``POST /api/recording/stop`` (JSON body ``{}``): record
  the run to a new MCAP file in ``record.dir`` (the server names it; a client never gives a
  path), and stop. 409 when already (or not) recording; a file that cannot be made is a 400
  that says why. The state's ``recording`` says where, how much, and why it stopped.

Every error is JSON ``{"error": "what went wrong and what to do"}`` of one line, never a
traceback (that goes to the server's log, and only for a bug): 400 a bad body (strict: numbers
are JSON numbers, ids JSON integers; a track id must be a tracked bottle, checked first), 413 a
body over 64 KiB, 415 a body that is not ``application/json``. A client that leaves in the
middle of its body is let go quietly.

**Access** (:class:`Guard`). On the loopback address anyone on the machine may connect. Bound
to any other address, the app needs a token (:func:`resolve_token`) on every request and
socket: the ``token`` query parameter (the URL printed at start has it), ``Authorization:
Bearer``, or the ``armvision_token`` cookie the page gets when it is opened with the token
(SameSite=Strict, so other sites cannot borrow it). Anything else gets 401 (a socket: closed
with 1008). Whatever the address, other web sites get nothing: the Host header must be one
of the server's own names (else 403: a DNS-rebinding page names its own host), a POST or a
socket that carries an Origin must carry the server's own (else 403; scripts send none), a
state-changing body must be JSON (an HTML form cannot send that), and no answer may be framed
(``X-Frame-Options``, ``Content-Security-Policy``).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import ipaddress
import json
import logging
import math
import os
import reprlib
import secrets
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from http.cookies import SimpleCookie
from pathlib import Path
from typing import Any, Literal
from urllib.parse import parse_qs

import cv2
import numpy as np
from fastapi import FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from scipy.spatial.transform import Rotation
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from armvision.config import Config
from armvision.errors import ArmvisionError
from armvision.geometry import pose_error
from armvision.runtime.recorder import Recorder
from armvision.runtime.state import SystemState
from armvision.runtime.system import DETECTORS, System
from armvision.runtime.view import annotated, depth_image

log = logging.getLogger("armvision.ui")

STATIC_DIR = Path(__file__).with_name("static")
TOKEN_ENV = "ARMVISION_UI_TOKEN"
COOKIE = "armvision_token"
Mode = Literal["sim", "real"]


# --------------------------------------------------------------------------- access


def is_loopback(host: str) -> bool:
    """True for the loopback interface (``127.0.0.1``, ``::1``, ``[::1]``, ``localhost``)."""
    host = host.lower().rstrip(".")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name: only reachable from elsewhere if it resolves there
        return False


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


@functools.cache  # the full name may need a DNS look-up: once per process, not per bind
def machine_names() -> frozenset[str]:
    """This machine's own names: its host name, ``<name>.local`` and its full name."""
    name = socket.gethostname().lower()
    names = {name, f"{name}.local"}
    with contextlib.suppress(OSError, UnicodeError):  # no resolver: the plain names will do
        names.add(socket.getfqdn().lower())
    return frozenset(n.rstrip(".") for n in names if n)


def split_host(value: str) -> tuple[str, int | None] | None:
    """A Host header (``name[:port]``, ``[v6][:port]``) as (host, port); None if it is none."""
    value = value.strip().lower()
    if value.startswith("["):
        end = value.find("]")
        host, rest = value[1:end], value[end + 1 :]
        if end < 0 or not _is_ip(host):
            return None
    else:
        host, sep, port = value.partition(":")
        rest = sep + port
    if rest and not (rest[0] == ":" and rest[1:].isdigit() and len(rest) <= 6):
        return None
    if not host or not all(c.isascii() and (c.isalnum() or c in "-._:%") for c in host):
        return None
    return host.rstrip("."), int(rest[1:]) if rest else None


DEFAULT_PORTS = {"http": 80, "https": 443}


def same_origin(origin: str, host_header: str) -> bool:
    """Is ``origin`` (a browser's Origin header) the server that ``host_header`` names?"""
    scheme, sep, netloc = origin.strip().lower().partition("://")
    if not sep or scheme not in DEFAULT_PORTS or "/" in netloc or "@" in netloc:
        return False
    theirs, ours = split_host(netloc), split_host(host_header)
    if theirs is None or ours is None:
        return False
    default = DEFAULT_PORTS[scheme]  # a Host without a port: the one the origin's scheme uses
    return theirs[0] == ours[0] and (theirs[1] or default) == (ours[1] or default)


MIN_TOKEN = 16
MAKE_TOKEN = "python -c 'import secrets; print(secrets.token_urlsafe(18))'"


def resolve_token(host: str, configured: str = "") -> str | None:
    """The token the app will require: ``$ARMVISION_UI_TOKEN``, else ``ui.token``, else a new
    random one when ``host`` is not the loopback, else None (no token on localhost). A token
    given must have at least 16 characters and no spaces (ArmvisionError saying how to make
    one)."""
    from_env = os.environ.get(TOKEN_ENV)
    token = from_env or configured
    if token:
        if len(token) < MIN_TOKEN or any(c.isspace() for c in token):
            where = f"${TOKEN_ENV}" if from_env else "ui.token"
            raise ArmvisionError(
                f"{where} must be at least {MIN_TOKEN} characters with no spaces (it has "
                f"{len(token)}): make one with {MAKE_TOKEN}"
            )
        return token
    return None if is_loopback(host) else secrets.token_urlsafe(18)


def _carried_token(scope: dict[str, Any], headers: dict[str, str]) -> str | None:
    query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
    if query.get("token"):
        return query["token"][0]
    auth = headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    cookie = SimpleCookie()
    try:
        cookie.load(headers.get("cookie", ""))
    except Exception:  # a malformed cookie header carries no token
        return None
    return cookie[COOKIE].value if COOKIE in cookie else None


SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

#: On every HTTP answer: no framing by other sites, no content sniffing, no embedding of the
#: video in other sites' pages, no Referer (the page's address may hold the token).
SECURITY_HEADERS = {
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Resource-Policy": "same-origin",
}


def content_security_policy(host: str) -> str:
    """The page's policy: its own script, style, images and sockets only (plus the ``data:``
    favicon), no plugins, no forms elsewhere, no framing. ``host``: a checked Host header."""
    return (
        "default-src 'self'; img-src 'self' data:; "
        f"connect-src 'self' ws://{host} wss://{host}; "
        "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
    )


class Guard:
    """ASGI middleware in front of the whole app; for every HTTP request and WebSocket:

    - the Host header must name this server (:meth:`OperatorUI.host_allowed`, against DNS
      rebinding): else 403;
    - a POST, and a socket, with an Origin must come from the server's own page: else 403 (no
      Origin at all is a script such as curl: browsers send one on every POST and socket);
    - the token, when there is one (:func:`resolve_token`): else 401;
    - every HTTP answer carries :data:`SECURITY_HEADERS` and :func:`content_security_policy`;
    - an exception out of the app is a bug: one traceback in the log, a one-line 500.

    A refused socket is closed before it is accepted (the client sees 403).
    """

    def __init__(self, app: Any, ui: OperatorUI) -> None:
        self.app = app
        self.ui = ui

    def refusal(self, scope: dict[str, Any], headers: dict[str, str]) -> tuple[int, str] | None:
        """(status, message) if this request or socket is refused, else None."""
        host = headers.get("host", "")
        parsed = split_host(host)
        if parsed is None or not self.ui.host_allowed(parsed[0]):
            named = _short(host) if host else "(none)"
            return 403, (
                f"this armvision server does not answer to the host name {named}: open it by "
                "its address, or add the name to ui.allowed_hosts"
            )
        origin = headers.get("origin")
        checked = scope["type"] == "websocket" or scope.get("method") not in SAFE_METHODS
        if checked and origin is not None and not same_origin(origin, host):
            return 403, (
                f"requests from another site ({_short(origin)}) are refused: use the armvision "
                "page itself, or a script that sends no Origin header"
            )
        token = self.ui.token
        if token is not None:
            carried = _carried_token(scope, headers)
            if carried is None or not secrets.compare_digest(carried.encode(), token.encode()):
                return 401, (
                    "this armvision server needs its access token: open the URL it printed "
                    "at start (…/?token=…), or send 'Authorization: Bearer <token>'"
                )
        return None

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        what = f"{scope.get('method', 'socket')} {_short(scope.get('path', ''), 80)}"
        refusal = self.refusal(scope, headers)
        if refusal is not None:
            status, message = refusal
            log.warning("refused %s: %s", what, message)
            if scope["type"] == "websocket":
                await receive()  # websocket.connect
                await send({"type": "websocket.close", "code": 1008})
                return
            extra = {"WWW-Authenticate": "Bearer"} if status == 401 else None
            response = JSONResponse({"error": message}, status_code=status, headers=extra)
            await response(scope, receive, self._secured(send, ""))  # no refused Host in it
            return
        started = False
        secured = self._secured(send, headers["host"]) if scope["type"] == "http" else send

        async def send_noting(message: dict[str, Any]) -> None:
            nonlocal started
            if message["type"] in ("http.response.start", "websocket.accept"):
                started = True
            await secured(message)

        try:
            await self.app(scope, receive, send_noting)
        except Exception as exc:  # a bug: once in the log, one line to the client
            log.exception("%s failed", what)
            if scope["type"] == "http" and not started:
                response = JSONResponse(
                    {"error": f"internal error ({type(exc).__name__}); see the server log"},
                    status_code=500,
                )
                await response(scope, receive, secured)

    @staticmethod
    def _secured(send: Any, host: str) -> Any:
        """``send`` adding the security headers to the answer's start."""
        extra = [(k.lower().encode(), v.encode()) for k, v in SECURITY_HEADERS.items()]
        if split_host(host) is not None:
            policy = content_security_policy(host.strip().lower())
        else:  # a refused Host: nothing of it goes into the answer
            policy = "default-src 'none'; frame-ancestors 'none'"
        extra.append((b"content-security-policy", policy.encode()))

        async def secured(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                have = {k.lower() for k, _ in message.get("headers", [])}
                message = dict(message)
                message["headers"] = [
                    *message.get("headers", []),
                    *(h for h in extra if h[0] not in have),
                ]
            await send(message)

        return secured


# --------------------------------------------------------------------------- actions


@dataclass(frozen=True)
class Action:
    """A control of the page: the task it runs and what it needs."""

    label: str
    params: frozenset[str] = frozenset()
    needs: Literal["bottle", "tags", "camera"] | None = None


#: The page's controls, in display order.
ACTIONS: dict[str, Action] = {
    "home": Action("Home"),
    "sleep": Action("Sleep"),
    "gripper_open": Action("Open gripper"),
    "gripper_close": Action("Close gripper"),
    "calibrate": Action("Calibrate", needs="camera"),
    "follow_tag": Action("Follow tag", frozenset({"tag_id", "duration_s"}), "tags"),
    "follow_bottle": Action("Follow bottle", frozenset({"track_id", "duration_s"}), "bottle"),
    "grab": Action("Grab bottle", frozenset({"track_id"}), "bottle"),
    "analyze": Action("Analyze bottle", frozenset({"track_id"}), "bottle"),
    "place": Action("Place", frozenset({"zone"})),
    "sort": Action("Sort bottles", frozenset({"by"}), "bottle"),
}


class ActionBody(BaseModel):
    """The parameters an action may take (each action accepts only its own). Strict: ids are
    JSON integers and the duration a JSON number, never a string or a boolean."""

    model_config = ConfigDict(extra="forbid", strict=True)
    track_id: int | None = Field(None, ge=0)
    tag_id: int | None = Field(None, ge=0)
    duration_s: float | None = Field(None, gt=0.0, le=3600.0)
    zone: str | None = Field(None, min_length=1, max_length=40)
    by: Literal["fill", "colour"] | None = None


#: What each parameter must be, for the messages.
PARAMETER_RULES = {
    "track_id": "a bottle's track id, a JSON integer (the page's list of tracks has them)",
    "tag_id": "a tag id, a JSON integer of 0 or more",
    "duration_s": "a number of seconds above 0 and at most 3600 (a JSON number, not a string)",
    "zone": "a zone's name of place.zones, a JSON string (the page's list has them)",
    "by": 'what to sort by: "fill" or "colour"',
}


class DetectorBody(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    enabled: bool


class RequestError(ArmvisionError):
    """A request the server turns down; ``status`` is its HTTP status."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


class ClientGone(Exception):  # noqa: N818 - an event, not an error of ours
    """The client closed its connection before its request body was in."""


#: The most a request body may be (the largest real one is under 100 bytes).
BODY_LIMIT = 64 * 1024
MESSAGE_LIMIT = 300


def _one_line(text: str, limit: int = MESSAGE_LIMIT) -> str:
    """``text`` on one line, at most ``limit`` characters, encodable (no lone surrogates)."""
    text = " ".join(text.split()).encode("utf-8", "backslashreplace").decode("utf-8")
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _short(value: Any, n: int = 40) -> str:
    """A short quotation of a value from a request (a prefix of a long one)."""
    r = reprlib.Repr()
    r.maxstring = r.maxother = r.maxlong = n
    r.maxlevel = 2
    r.maxlist = r.maxtuple = r.maxdict = r.maxset = 4
    try:
        text = r.repr(value)
    except Exception:  # e.g. an int too long to print: say what it is
        text = f"a {type(value).__name__}"
    return _one_line(text, n + 12)


def _id_list(ids: list[int], limit: int = 10) -> str:
    text = ", ".join(f"#{i}" for i in ids[:limit])
    return (text + (", …" if len(ids) > limit else "")) or "none"


def _refuse_constant(name: str) -> Any:
    raise RequestError(400, f"{name} is not a JSON number: send a finite number")


async def read_json(request: Request) -> Any:
    """The request's JSON body (an empty one is ``{}``): RequestError 415 unless it says
    ``Content-Type: application/json``, 413 above :data:`BODY_LIMIT`, 400 unless it is UTF-8
    JSON; ClientGone if the client leaves before it is in."""
    content_type = request.headers.get("content-type", "")
    if content_type.split(";")[0].strip().lower() != "application/json":
        got = _short(content_type) if content_type else "none"
        raise RequestError(
            415, f"send the body as JSON with 'Content-Type: application/json' (it was {got})"
        )
    too_big = RequestError(
        413, f"the body is over {BODY_LIMIT // 1024} KiB: send only the action's parameters"
    )
    length = request.headers.get("content-length", "")
    if length.isdigit() and (len(length) > 9 or int(length) > BODY_LIMIT):
        raise too_big
    raw = bytearray()
    try:
        async for chunk in request.stream():
            raw += chunk
            if len(raw) > BODY_LIMIT:
                raise too_big
    except ClientDisconnect:
        raise ClientGone from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise RequestError(400, "the body is not UTF-8 text: send JSON encoded as UTF-8") from None
    if not text.strip():
        return {}
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except RecursionError:
        raise RequestError(
            400, "the body's JSON is nested too deeply: send one flat object of parameters"
        ) from None
    except json.JSONDecodeError as exc:
        raise RequestError(
            400,
            f"the body is not valid JSON ({exc.msg} at character {exc.pos}): send an object "
            'of parameters such as {} or {"track_id": 3}',
        ) from None
    except ValueError:  # an integer of more digits than Python converts
        raise RequestError(
            400, "the body has a number too long to read: send ids and seconds as plain numbers"
        ) from None


def _no_action(name: str) -> RequestError:
    return RequestError(404, f"no action {_short(name)}; the actions are {', '.join(ACTIONS)}")


def _action_params(name: str, action: Action, body: Any) -> ActionBody:
    """The parameters of action ``name`` from a request body (RequestError 400 if wrong)."""
    takes = f"it takes {', '.join(sorted(action.params))}" if action.params else "it takes none"
    if not isinstance(body, dict):
        raise RequestError(
            400,
            f"{name}: the body must be a JSON object of parameters ({takes}), not {_short(body)}",
        )
    try:
        params = ActionBody.model_validate(body)
    except ValidationError as exc:
        errors = exc.errors()
        e = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
        key = e["loc"][0] if e["loc"] else "body"
        more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
        if e["type"] == "extra_forbidden":
            message = f"{name}: unknown parameter {_short(key)}; {takes}"
        else:
            rule = PARAMETER_RULES.get(str(key), "something else")
            message = f"{name}: {key} must be {rule}, not {_short(e.get('input'))}"
        raise RequestError(400, message + more) from None
    given = {k for k, v in params.model_dump().items() if v is not None}
    if given - action.params:
        raise RequestError(
            400, f"{name} takes no {', '.join(sorted(given - action.params))} ({takes})"
        )
    return params


def _no_parameters(name: str, body: Any) -> None:
    """RequestError 400 unless ``body`` is an empty JSON object."""
    if body != {} or not isinstance(body, dict):
        raise RequestError(400, f"{name} takes no parameters: send {{}}, not {_short(body)}")


def _new_recording_path(folder: Path) -> Path:
    """``run-<date>-<time>.mcap`` in ``folder``, numbered if that name is taken."""
    stem = time.strftime("run-%Y%m%d-%H%M%S")
    path = folder / f"{stem}.mcap"
    n = 1
    while path.exists():
        n += 1
        path = folder / f"{stem}-{n}.mcap"
    return path


def _detector_body(name: str, body: Any) -> DetectorBody:
    """The switch of detector ``name`` from a request body (RequestError 400 if wrong)."""
    what = f'{name}: send {{"enabled": true}} or {{"enabled": false}}'
    if not isinstance(body, dict):
        raise RequestError(400, f"{what}, not {_short(body)}")
    try:
        return DetectorBody.model_validate(body)
    except ValidationError as exc:
        e = exc.errors()[0]
        if e["type"] == "extra_forbidden":
            raise RequestError(400, f"{what} (unknown parameter {_short(e['loc'][0])})") from None
        if e["type"] == "missing":
            raise RequestError(400, what) from None
        raise RequestError(
            400, f"{name}: enabled must be true or false (a JSON boolean), not {_short(e['input'])}"
        ) from None


# --------------------------------------------------------------------------- state


def _finite(value: Any) -> Any:
    """JSON-able with no NaN/inf (JavaScript's JSON.parse rejects them): those become null."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _r(values: Any, n: int) -> list[float]:
    return [round(float(v), n) for v in values]


def state_payload(
    state: SystemState, system: System, mode: Mode, recording: Recorder | None = None
) -> dict[str, Any]:
    """Everything the page shows, as a JSON-able dict (the contract with static/app.js);
    ``recording``: the UI's newest recorder."""
    model = getattr(system.arm, "model", None)
    fusion = state.fusion
    q = fusion.joint_positions
    ee = None
    if fusion.T_base_ee is not None and fusion.ee is not None:
        T = fusion.T_base_ee
        ee = {
            "xyz_m": _r(T[:3, 3], 4),
            "rpy_deg": _r(Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True), 2),
            "sigma_mm": round(fusion.ee.sigma_mm, 2),
        }
    arm = {
        "joint_names": list(model.joint_names) if model is not None else [],
        "joints_deg": None if q is None else _r(np.degrees(q), 2),
        "lower_deg": [] if model is None else _r(np.degrees(model.lower), 1),
        "upper_deg": [] if model is None else _r(np.degrees(model.upper), 1),
        "ee": ee,
        "finger_m": state.finger_position,
        "moving": bool(getattr(system.arm, "moving", False)),
    }
    tracks = []
    for t in state.tracks:
        liquid = state.liquid.get(t.id)
        tracks.append(
            {
                "id": t.id,
                "label": t.label,
                "position_m": _r(t.p_base, 4),
                "sigma_mm": round(t.sigma_mm, 2),
                "velocity_mps": _r(t.v_base, 4),
                "radius_m": t.radius,
                "height_m": t.height,
                "hits": t.hits,
                "age_s": round(max(state.time - t.last_seen, 0.0), 3),
                "liquid": None if liquid is None else liquid.to_dict(),
            }
        )
    frame = state.frame
    return _finite(
        {
            "mode": mode,
            "time": state.time,
            "frame": None
            if frame is None
            else {
                "index": frame.index,
                "timestamp": frame.timestamp,
                "width": int(frame.color.shape[1]),
                "height": int(frame.color.shape[0]),
            },
            "arm": arm,
            "calibration": {
                **state.calibration.to_dict(),
                "drift": state.drift.to_dict(),
                "camera": camera_pose_dict(state),
            },
            "health": {name: h.to_dict() for name, h in state.health.items()},
            "detectors": dict(state.detectors),
            "tracks": tracks,
            "planning_scene": state.planning_scene.to_dict(),
            "tags": [
                {"id": tag.id, "distance_m": round(float(np.linalg.norm(tag.T_cam_tag[:3, 3])), 3)}
                for tag in state.tags
            ],
            "task": state.task.to_dict(),
            "busy": state.task.active,
            "actions": action_states(state),
            "recording": None if recording is None else recording.status(),
            "zones": {name: list(rect) for name, rect in system.config.place.zones.items()},
        }
    )


def camera_pose_dict(state: SystemState) -> dict[str, Any]:
    """The camera pose the system works with (the calibration refined by fusion), and how far
    the refinement has moved it from the calibration."""
    T = state.T_base_cam
    dp, dr = pose_error(T, state.calibration.T_base_cam)
    return {
        "T_base_cam": np.asarray(T).tolist(),
        "from_calibration_mm": round(1000.0 * float(dp), 2),
        "from_calibration_deg": round(math.degrees(float(dr)), 3),
    }


def action_states(state: SystemState) -> dict[str, dict[str, Any]]:
    """Which controls may be used now, and why not."""
    busy = state.task.active
    camera = state.health.get("camera")
    out = {}
    for name, action in ACTIONS.items():
        reason = None
        if busy:
            reason = f"{state.task.name} is running: wait for it or press Stop"
        elif action.needs in ("bottle", "tags") and not state.calibration.calibrated:
            reason = "not calibrated: press Calibrate first (clear the table)"
        elif action.needs in ("bottle", "tags") and state.drift.drifted:
            reason = state.drift.refusal()
        elif action.needs == "bottle" and not state.bottles():
            reason = "no bottle tracked (is object detection on?)"
        elif action.needs == "tags" and not state.detectors.get("tags", False):
            reason = "tag detection is off"
        elif action.needs == "camera" and camera is not None and not camera.alive:
            reason = "the camera is not running"
        out[name] = {"label": action.label, "enabled": reason is None, "reason": reason}
    return out


# --------------------------------------------------------------------------- the app


class OperatorUI:
    """The app and what it serves from: ``system`` (started, realtime), ``mode``,
    ``token`` (None: no token), ``calibration_path``: where Calibrate saves (None: not
    saved)."""

    def __init__(
        self,
        system: System,
        config: Config,
        mode: Mode,
        token: str | None = None,
        calibration_path: str | os.PathLike[str] | None = None,
    ) -> None:
        if system.lockstep:
            raise ArmvisionError("the UI needs a running system (realtime), not a lockstep one")
        self.system = system
        self.config = config
        self.settings = config.ui
        self.mode = mode
        self.token = token
        self.calibration_path = calibration_path
        self.closing = threading.Event()
        self._submit = threading.Lock()
        self._payload: tuple[float, str] = (-math.inf, "")
        self._payload_lock = threading.Lock()
        self._jpeg: dict[str, tuple[int, bytes]] = {}
        self._jpeg_lock = threading.Lock()
        self._allowed_hosts = frozenset(
            h.strip().lower().strip("[]").rstrip(".") for h in self.settings.allowed_hosts
        )
        self.recording: Recorder | None = None  # the newest recorder (stopped or not)
        self._recording_lock = threading.Lock()
        self.bind(self.settings.host)  # until a Server says where it listens
        self.app = self._build()

    # ---------------------------------------------------------------- serving helpers

    def payload(self, fresh: bool = False) -> str:
        """The state JSON, made at most once per half state period however many sockets
        (``fresh``: made now, for a request that must see its own last action)."""
        period = 1.0 / self.settings.state_hz
        now = time.monotonic()
        with self._payload_lock:
            made, text = self._payload
            if text and not fresh and now - made < 0.5 * period:
                return text
        text = json.dumps(
            state_payload(self.system.snapshot(), self.system, self.mode, self.recording)
        )
        with self._payload_lock:
            self._payload = (now, text)
        return text

    def jpeg(self, view: str) -> tuple[int, bytes] | None:
        """(frame index, JPEG) of the newest frame in ``view``; encoded once per frame."""
        state = self.system.snapshot()
        frame = state.frame
        if frame is None:
            return None
        with self._jpeg_lock:
            cached = self._jpeg.get(view)
            if cached is not None and cached[0] == frame.index:
                return cached
        image = (
            depth_image(frame.depth, self.settings.depth_min_m, self.settings.depth_max_m)
            if view == "depth"
            else annotated(state, self.config.tag.size, zones=self.config.place.zones)
        )
        if image is None:
            return None
        ok, buf = cv2.imencode(
            ".jpg",
            cv2.cvtColor(image, cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_JPEG_QUALITY, self.settings.jpeg_quality],
        )
        if not ok:
            raise ArmvisionError("JPEG encoding failed")
        result = (frame.index, buf.tobytes())
        with self._jpeg_lock:
            self._jpeg[view] = result
        return result

    def start_action(self, name: str, body: Any) -> int:
        """Start action ``name`` with the parameters in ``body`` (a request's JSON) in the
        background; its task id. RequestError if not: 404 no such action, 400 bad parameters
        or ids that name nothing (decided first), 409 not now (busy, or what it needs)."""
        action = ACTIONS.get(name)
        if action is None:
            raise _no_action(name)
        params = _action_params(name, action, body)
        with self._submit:
            state = self.system.snapshot()
            self._check_ids(state, params)
            refusal = action_states(state)[name]["reason"]  # busy first, then what it needs
            if refusal is not None:
                raise RequestError(409, f"{action.label}: {refusal}")
            fn, kwargs = self._task(name, params)
            task_id = self.system.submit(name, fn, **kwargs)
        self.changed()
        return task_id

    def start_recording(self, body: Any) -> dict[str, Any]:
        """Record the run to a new file in ``record.dir`` (RequestError 400 for a body with
        parameters or a file that cannot be made, 409 if recording already)."""
        from armvision.runtime.recorder import Recorder, RecordingError

        _no_parameters("recording/start", body)
        with self._recording_lock:
            current = self.recording
            if current is not None and current.active:
                raise RequestError(
                    409, f"already recording to {current.path}: stop that recording first"
                )
            folder = Path(self.config.record.dir)
            try:
                folder.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise RequestError(
                    400,
                    f"cannot record into {folder} ({exc.strerror or exc}): set record.dir to a "
                    "folder you can write to",
                ) from None
            path = _new_recording_path(folder)
            live = current is not None and current.live is not None and not current.stopped.is_set()
            try:
                if live:  # the live view's recorder writes the file too
                    assert current is not None
                    current.start_file(path)
                    recorder = current
                else:
                    recorder = Recorder(path, self.config, wait=False).open()
            except RecordingError as exc:
                raise RequestError(400, str(exc)) from None
            if not live:
                self.system.attach_recorder(recorder)
            self.recording = recorder
        self.changed()
        return {"recording": recorder.status()}

    def stop_recording(self, body: Any) -> dict[str, Any]:
        """Stop recording and finish the file (RequestError 409 if not recording)."""
        from armvision.runtime.recorder import RecordingError

        _no_parameters("recording/stop", body)
        with self._recording_lock:
            recorder = self.recording
            if recorder is None or not recorder.active:
                raise RequestError(409, "not recording: press Record first")
            if recorder.live is not None:
                try:
                    recorder.stop_file()  # the live view goes on
                except RecordingError as exc:
                    raise RequestError(409, str(exc)) from None
            else:
                self.system.detach_recorder()
                recorder.stop()
        self.changed()
        return {"recording": recorder.status()}

    def _check_ids(self, state: SystemState, params: ActionBody) -> None:
        """RequestError 400 for a track id that is no tracked bottle, or the gripper's own tag
        as the tag to follow, naming what there is."""
        if params.track_id is not None:
            track = state.track(params.track_id)
            if track is None or track.label != "bottle":
                have = _id_list([t.id for t in state.bottles()])
                raise RequestError(
                    400,
                    f"no bottle track #{_short(params.track_id)} (bottles tracked now: {have}): "
                    "pick one of those, or none for the nearest",
                )
        zones = self.config.place.zones
        if params.zone is not None and params.zone not in zones:
            raise RequestError(
                400,
                f"no zone {_short(params.zone)} in place.zones (zones: "
                f"{', '.join(sorted(zones)) or 'none'})",
            )
        own = self.config.tag.id
        if params.tag_id is not None and params.tag_id == own:
            seen = sorted({t.id for t in state.tags} - {own})
            in_view = ", ".join(str(i) for i in seen[:10]) or "none"
            raise RequestError(
                400,
                f"tag {own} is the gripper's own tag and cannot be followed (tags in view now: "
                f"{in_view}): pass one of those, or no tag_id for follow.tag_id "
                f"({self.config.follow.tag_id})",
            )

    def bind(self, host: str) -> None:
        """Serve on ``host`` (the address listened on): which Host names are answered."""
        self.bound_host = host
        self._machine_names = frozenset() if is_loopback(host) else machine_names()

    def host_allowed(self, name: str) -> bool:
        """May a request name ``name`` as its Host (no port, no brackets)? The loopback names
        and ``ui.allowed_hosts`` always; bound off the loopback, also IP literals (a DNS
        rebinding page has a name, not an address) and this machine's names."""
        name = name.lower().rstrip(".")
        if name in self._allowed_hosts or is_loopback(name):
            return True
        if is_loopback(self.bound_host):
            return False
        return _is_ip(name) or name in self._machine_names or name == self.bound_host.lower()

    def changed(self) -> None:
        """Something was asked of the system: the next state message is made afresh."""
        with self._payload_lock:
            self._payload = (-math.inf, "")

    def _task(self, name: str, p: ActionBody) -> tuple[Callable[..., Any], dict[str, Any]]:
        from armvision.tasks import basic

        duration = p.duration_s or self.settings.follow_duration_s
        if name in ("home", "sleep", "gripper_open", "gripper_close"):
            return getattr(basic, name), {}
        if name == "calibrate":
            from armvision.tasks.calibrate import calibrate

            return calibrate, {
                "save_path": self.calibration_path,
                "source": f"armvision ui ({self.mode})",
            }
        if name == "grab":
            from armvision.tasks.grab import grab

            return grab, {"track_id": p.track_id}
        if name == "analyze":
            from armvision.tasks.analyze import analyze

            return analyze, {"track_id": p.track_id}
        if name == "place":
            from armvision.tasks.place import place

            return place, {"zone": p.zone or next(iter(self.config.place.zones))}
        if name == "sort":
            from armvision.tasks.sort import sort

            return sort, {"by": p.by}
        from armvision.tasks.follow import follow

        if name == "follow_tag":
            return follow, {"target": "tag", "tag_id": p.tag_id, "duration_s": duration}
        return follow, {"target": "bottle", "track_id": p.track_id, "duration_s": duration}

    # ---------------------------------------------------------------- routes

    def _build(self) -> FastAPI:
        app = FastAPI(title="armvision", docs_url=None, redoc_url=None, openapi_url=None)
        self._add_error_handlers(app)
        self._add_page_routes(app)
        self._add_state_routes(app)
        self._add_video_routes(app)
        self._add_control_routes(app)
        app.add_middleware(Guard, ui=self)
        return app

    def _add_error_handlers(self, app: FastAPI) -> None:
        """The exception handlers: an error as ``{"error": one line}`` with its status (a client
        that left before its body was in: a bare 400)."""

        def error(message: str, status: int) -> JSONResponse:
            return JSONResponse({"error": _one_line(message)}, status_code=status)

        @app.exception_handler(RequestError)
        async def _request_error(request: Request, exc: RequestError) -> JSONResponse:
            return error(str(exc), exc.status)

        @app.exception_handler(ArmvisionError)
        async def _armvision_error(request: Request, exc: ArmvisionError) -> JSONResponse:
            return error(str(exc), 400)

        @app.exception_handler(ClientGone)
        async def _client_gone(request: Request, exc: ClientGone) -> Response:
            log.info(
                "%s %s: the client left before its body was in",
                request.method,
                _short(request.url.path, 80),
            )
            return Response(status_code=400)  # nobody to read it

        @app.exception_handler(StarletteHTTPException)
        async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
            path = _short(request.url.path, 80)
            if exc.status_code == 404:
                detail = f"nothing at {path}: the page is at /, the API under /api/"
            elif exc.status_code == 405:
                allowed = (exc.headers or {}).get("Allow", "another method")
                detail = f"{request.method} is not for {path}: use {allowed}"
            else:
                detail = exc.detail if isinstance(exc.detail, str) else "request refused"
            return error(detail, exc.status_code)

        @app.exception_handler(RequestValidationError)
        async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
            return error(
                f"bad request to {_short(request.url.path, 80)}: see the API list "
                "in armvision/ui/server.py",
                400,
            )

    def _add_page_routes(self, app: FastAPI) -> None:
        """The page (setting the token cookie) and its static files."""
        ui = self

        @app.get("/")
        async def index(request: Request) -> Response:
            response = FileResponse(
                STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"}
            )
            if ui.token is not None:
                response.set_cookie(COOKIE, ui.token, httponly=True, samesite="strict")
            return response

        app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    def _add_state_routes(self, app: FastAPI) -> None:
        """The state: on request, and pushed over a WebSocket at ``ui.state_hz``."""
        ui = self

        @app.get("/api/state")
        async def get_state() -> Response:
            return Response(ui.payload(fresh=True), media_type="application/json")

        @app.websocket("/ws/state")
        async def ws_state(ws: WebSocket) -> None:
            await ws.accept()
            period = 1.0 / ui.settings.state_hz
            loop = asyncio.get_running_loop()
            next_time = loop.time()
            try:
                while not ui.closing.is_set():
                    await ws.send_text(ui.payload())
                    next_time = max(next_time + period, loop.time())
                    await asyncio.sleep(next_time - loop.time())
                await ws.close(1001)  # going away: the server shuts down
            except (WebSocketDisconnect, RuntimeError):
                return  # the page went away

    def _add_video_routes(self, app: FastAPI) -> None:
        """The newest camera frame as a JPEG, and the MJPEG stream."""
        ui = self

        def _view(view: str) -> str:
            if view not in ("color", "depth"):
                raise RequestError(400, f"view must be 'color' or 'depth', not {_short(view)}")
            return view

        @app.get("/api/frame.jpg")
        async def frame_jpg(view: str = "color") -> Response:
            got = await run_in_threadpool(ui.jpeg, _view(view))
            if got is None:
                raise RequestError(503, "no camera frame yet: is the camera running?")
            return Response(got[1], media_type="image/jpeg", headers={"Cache-Control": "no-store"})

        @app.get("/stream.mjpg")
        async def stream(view: str = "color") -> StreamingResponse:
            view = _view(view)

            async def frames():
                period = 1.0 / ui.settings.video_fps
                last = -1
                while not ui.closing.is_set():
                    got = await run_in_threadpool(ui.jpeg, view)
                    if got is not None and got[0] != last:
                        last, data = got
                        yield (
                            b"--frame\r\nContent-Type: image/jpeg\r\n"
                            + f"Content-Length: {len(data)}\r\n\r\n".encode()
                            + data
                            + b"\r\n"
                        )
                    await asyncio.sleep(period)

            return StreamingResponse(
                frames(),
                media_type="multipart/x-mixed-replace; boundary=frame",
                headers={"Cache-Control": "no-store"},
            )

    def _add_control_routes(self, app: FastAPI) -> None:
        """Starting an action, the stop, and switching detectors."""
        ui = self

        @app.post("/api/actions/{name}", status_code=202)
        async def action(name: str, request: Request) -> dict[str, Any]:
            if name not in ACTIONS:  # before the body: the name is the mistake
                raise _no_action(name)
            body = await read_json(request)
            task_id = await run_in_threadpool(ui.start_action, name, body)
            return {"task_id": task_id, "name": name}

        @app.post("/api/stop")
        async def stop() -> dict[str, Any]:
            # A safety control: no body or content type is asked for (the Guard still refuses
            # other sites).
            await run_in_threadpool(ui.system.stop_task)
            ui.changed()
            return {"stopped": True}

        @app.post("/api/detectors/{name}")
        async def detector(name: str, request: Request) -> dict[str, Any]:
            if name not in DETECTORS:
                raise RequestError(
                    404, f"no detector {_short(name)}; the detectors are {', '.join(DETECTORS)}"
                )
            body = _detector_body(name, await read_json(request))
            ui.system.set_detector(name, body.enabled)
            ui.changed()
            return {"detectors": dict(ui.system.enabled)}

        @app.post("/api/recording/{what}")
        async def recording(what: str, request: Request) -> dict[str, Any]:
            if what not in ("start", "stop"):
                raise RequestError(
                    404, f"no recording control {_short(what)}; they are start and stop"
                )
            body = await read_json(request)
            work = ui.start_recording if what == "start" else ui.stop_recording
            return await run_in_threadpool(work, body)


# --------------------------------------------------------------------------- serving


def listen(host: str, port: int) -> socket.socket:
    """A socket bound to ``host``:``port`` (0: any free port); ArmvisionError saying what to do
    if it cannot be (bind before building the system, so a busy port fails at once)."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(128)  # connections queue from now on, before the server takes them
    except OSError as exc:
        raise ArmvisionError(
            f"cannot listen on {host}:{port} ({exc.strerror or exc}): is another armvision ui "
            "running? Choose another --port, or a --host this machine has"
        ) from None
    return sock


class Server:
    """uvicorn serving an :class:`OperatorUI` on a socket from :func:`listen`, in the
    foreground (:meth:`run`, Ctrl-C ends it) or in a thread (:meth:`start` / :meth:`stop`)."""

    def __init__(self, ui: OperatorUI, sock: socket.socket) -> None:
        import uvicorn

        self.ui = ui
        self.socket = sock
        self.host = str(sock.getsockname()[0])
        self.port = int(sock.getsockname()[1])
        ui.bind(self.host)
        self.server = uvicorn.Server(
            uvicorn.Config(
                ui.app,
                log_level="warning",
                timeout_graceful_shutdown=2,
                lifespan="off",
            )
        )
        self._thread: threading.Thread | None = None

    def url(self, with_token: bool = True) -> str:
        """The page's address (with the token, when there is one and ``with_token``)."""
        host = self.host
        if host in ("0.0.0.0", "::"):
            host = socket.gethostname()
        elif ":" in host:
            host = f"[{host}]"
        url = f"http://{host}:{self.port}/"
        if with_token and self.ui.token is not None:
            url += f"?token={self.ui.token}"
        return url

    def run(self) -> None:
        """Serve until Ctrl-C (or :meth:`stop` from another thread)."""
        try:
            self.server.run(sockets=[self.socket])
        finally:
            self.ui.closing.set()

    def start(self, timeout_s: float = 10.0) -> Server:
        """Serve from a background thread; returns once it accepts connections."""
        self._thread = threading.Thread(target=self.run, name="armvision-ui", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise ArmvisionError(f"the UI server did not start on {self.host}:{self.port}")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        """End the streams and sockets, then the server."""
        self.ui.closing.set()
        self.server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self.socket.close()
