"""The operator web UI: a FastAPI app around a running :class:`~armvision.runtime.system.System`.

One page (``static/``: plain HTML, JS and CSS, no build step) talks to these endpoints:

- ``GET /``: the page; ``GET /static/...``: its script and style.
- ``WS /ws/state``: the state as JSON (:func:`state_payload`), ``ui.state_hz`` times a second.
- ``GET /api/state``: the same, once.
- ``GET /stream.mjpg?view=color|depth``: MJPEG of the annotated colour image or of the
  colourised depth, at most ``ui.video_fps``; ``GET /api/frame.jpg?view=...``: one JPEG.
- ``POST /api/actions/{name}`` (JSON body of the action's parameters): start a task in the
  background, 202 with its id; 409 while another task runs (press Stop first).
- ``POST /api/stop``: Stop, always accepted: the arm halts where it is, the task ends.
- ``POST /api/detectors/{name}`` ``{"enabled": bool}``: switch tag, object or liquid detection.

Every error is JSON ``{"error": "what went wrong and what to do"}``, never a traceback (that
goes to the server's log).

**Access.** On the loopback address anyone on the machine may connect. Bound to any other
address, the app needs a token (:func:`resolve_token`) on every request and socket: the
``token`` query parameter (the URL printed at start has it), ``Authorization: Bearer``, or the
``armvision_token`` cookie the page gets when it is opened with the token (SameSite=Strict, so
other sites cannot borrow it). Anything else gets 401 (a socket: closed with 1008).
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import math
import os
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
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from scipy.spatial.transform import Rotation
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from armvision.config import Config
from armvision.errors import ArmvisionError
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
    """True for the loopback interface (``127.0.0.1``, ``::1``, ``localhost``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name: only reachable from elsewhere if it resolves there
        return False


def resolve_token(host: str, configured: str = "") -> str | None:
    """The token the app will require: ``$ARMVISION_UI_TOKEN``, else ``ui.token``, else a new
    random one when ``host`` is not the loopback, else None (no token on localhost)."""
    token = os.environ.get(TOKEN_ENV) or configured
    if token:
        return token
    return None if is_loopback(host) else secrets.token_urlsafe(18)


class TokenGuard:
    """ASGI middleware: every HTTP request and WebSocket must carry the token."""

    def __init__(self, app: Any, token: str) -> None:
        self.app = app
        self.token = token

    def _carried(self, scope: dict[str, Any]) -> str | None:
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        if query.get("token"):
            return query["token"][0]
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        auth = headers.get("authorization", "")
        if auth.lower().startswith("bearer "):
            return auth[7:].strip()
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:  # a malformed cookie header carries no token
            return None
        return cookie[COOKIE].value if COOKIE in cookie else None

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        carried = self._carried(scope)
        if carried is not None and secrets.compare_digest(carried.encode(), self.token.encode()):
            await self.app(scope, receive, send)
            return
        log.warning("refused %s %s: no valid token", scope["type"], scope.get("path"))
        if scope["type"] == "websocket":
            await receive()  # websocket.connect
            await send({"type": "websocket.close", "code": 1008})
            return
        response = JSONResponse(
            {
                "error": "this armvision server needs its access token: open the URL it "
                "printed at start (…/?token=…), or send 'Authorization: Bearer <token>'"
            },
            status_code=401,
            headers={"WWW-Authenticate": "Bearer"},
        )
        await response(scope, receive, send)


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
}


class ActionBody(BaseModel):
    """The parameters an action may take (each action accepts only its own)."""

    model_config = ConfigDict(extra="forbid")
    track_id: int | None = Field(None, ge=0)
    tag_id: int | None = Field(None, ge=0)
    duration_s: float | None = Field(None, gt=0.0, le=3600.0)


class DetectorBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    enabled: bool


class RequestError(ArmvisionError):
    """A request the server turns down; ``status`` is its HTTP status."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def _validation_message(exc: ValidationError) -> str:
    parts = []
    for e in exc.errors():
        key = ".".join(str(p) for p in e["loc"]) or "body"
        if e["type"] == "extra_forbidden":
            parts.append(f"unknown parameter '{key}'")
        else:
            parts.append(f"'{key}': {e['msg']} (got {e.get('input')!r})")
    return "; ".join(parts)


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


def state_payload(state: SystemState, system: System, mode: Mode) -> dict[str, Any]:
    """Everything the page shows, as a JSON-able dict (the contract with static/app.js)."""
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
            "calibration": state.calibration.to_dict(),
            "health": {name: h.to_dict() for name, h in state.health.items()},
            "detectors": dict(state.detectors),
            "tracks": tracks,
            "tags": [
                {"id": tag.id, "distance_m": round(float(np.linalg.norm(tag.T_cam_tag[:3, 3])), 3)}
                for tag in state.tags
            ],
            "task": state.task.to_dict(),
            "busy": state.task.active,
            "actions": action_states(state),
        }
    )


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
        text = json.dumps(state_payload(self.system.snapshot(), self.system, self.mode))
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
        if view == "depth":
            image = depth_image(frame.depth, self.settings.depth_min_m, self.settings.depth_max_m)
        else:
            image = annotated(state, self.config.tag.size)
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

    def start_action(self, name: str, body: dict[str, Any]) -> int:
        """Start action ``name`` in the background; its task id (RequestError if not now)."""
        action = ACTIONS.get(name)
        if action is None:
            raise RequestError(404, f"no action {name!r}; the actions are {', '.join(ACTIONS)}")
        try:
            params = ActionBody.model_validate(body)
        except ValidationError as exc:
            raise RequestError(400, f"{name}: {_validation_message(exc)}") from None
        given = {k for k, v in params.model_dump().items() if v is not None}
        if given - action.params:
            raise RequestError(
                400,
                f"{name} takes no {', '.join(sorted(given - action.params))}"
                + (f" (it takes {', '.join(sorted(action.params))})" if action.params else ""),
            )
        with self._submit:
            state = self.system.snapshot()
            refusal = action_states(state)[name]["reason"]  # busy first, then what it needs
            if refusal is not None:
                raise RequestError(409, f"{action.label}: {refusal}")
            if params.track_id is not None:
                track = state.track(params.track_id)
                if track is None or track.label != "bottle":
                    have = ", ".join(f"#{t.id}" for t in state.bottles()) or "none"
                    raise RequestError(
                        400, f"no bottle track #{params.track_id} (bottles tracked now: {have})"
                    )
            fn, kwargs = self._task(name, params)
            task_id = self.system.submit(name, fn, **kwargs)
        self.changed()
        return task_id

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
        from armvision.tasks.follow import follow

        if name == "follow_tag":
            return follow, {"target": "tag", "tag_id": p.tag_id, "duration_s": duration}
        return follow, {"target": "bottle", "track_id": p.track_id, "duration_s": duration}

    # ---------------------------------------------------------------- routes

    def _build(self) -> FastAPI:
        app = FastAPI(title="armvision", docs_url=None, redoc_url=None, openapi_url=None)
        ui = self

        @app.exception_handler(RequestError)
        async def _request_error(request: Request, exc: RequestError) -> JSONResponse:
            return JSONResponse({"error": str(exc)}, status_code=exc.status)

        @app.exception_handler(ArmvisionError)
        async def _armvision_error(request: Request, exc: ArmvisionError) -> JSONResponse:
            return JSONResponse({"error": str(exc)}, status_code=400)

        @app.exception_handler(StarletteHTTPException)
        async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
            detail = exc.detail if isinstance(exc.detail, str) else "request refused"
            if exc.status_code == 404:
                detail = f"nothing at {request.url.path}"
            return JSONResponse({"error": detail}, status_code=exc.status_code)

        @app.exception_handler(Exception)
        async def _crash(request: Request, exc: Exception) -> JSONResponse:
            log.exception("%s %s failed", request.method, request.url.path)
            return JSONResponse(
                {"error": f"internal error ({type(exc).__name__}: {exc}); see the server log"},
                status_code=500,
            )

        @app.get("/")
        async def index(request: Request) -> Response:
            response = FileResponse(
                STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"}
            )
            if ui.token is not None:
                response.set_cookie(COOKIE, ui.token, httponly=True, samesite="strict")
            return response

        app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

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

        def _view(view: str) -> str:
            if view not in ("color", "depth"):
                raise RequestError(400, f"view must be 'color' or 'depth', not {view!r}")
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

        @app.post("/api/actions/{name}", status_code=202)
        async def action(name: str, request: Request) -> dict[str, Any]:
            raw = await request.body()
            try:
                body = json.loads(raw) if raw.strip() else {}
            except json.JSONDecodeError as exc:
                raise RequestError(400, f"the body must be JSON: {exc}") from None
            if not isinstance(body, dict):
                raise RequestError(400, "the body must be a JSON object of parameters")
            task_id = await run_in_threadpool(ui.start_action, name, body)
            return {"task_id": task_id, "name": name}

        @app.post("/api/stop")
        async def stop() -> dict[str, Any]:
            await run_in_threadpool(ui.system.stop_task)
            ui.changed()
            return {"stopped": True}

        @app.post("/api/detectors/{name}")
        async def detector(name: str, request: Request) -> dict[str, Any]:
            if name not in DETECTORS:
                raise RequestError(
                    404, f"no detector {name!r}; the detectors are {', '.join(DETECTORS)}"
                )
            try:
                body = DetectorBody.model_validate_json(await request.body() or b"{}")
            except ValidationError as exc:
                raise RequestError(400, f"{name}: {_validation_message(exc)}") from None
            ui.system.set_detector(name, body.enabled)
            ui.changed()
            return {"detectors": dict(ui.system.enabled)}

        if self.token is not None:
            app.add_middleware(TokenGuard, token=self.token)
        return app


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
