"""`demoforge annotate`: a local web page to click a take's object keypoints and mark open/close ranges.

A standard-library HTTP server on loopback serves one static page (lib/annotate/page.html) and a
small JSON API over the take. Every request first passes the session's RequestGate
(demoforge.lib.annotate.request_gate: the per-session token of the printed URL, Host, Origin,
content type, body size), whatever its route:

    GET  /?token=T             the page
    GET  /api/state            take, camera, task (keypoints per object, arms), the current
                               annotations (annotations.json when there is one), fingertip distances
                               and the automatic method's closed ranges from an earlier ingest
    GET  /api/frame/N.jpg      frame N as JPEG
    POST /api/points           {"frame": N, "uv": [[u, v], ...]} -> depth, camera and world point per click
    POST /api/save             {"frame", "points": {name: [u, v]}, "ranges": {"left": [[s, e]], ...},
                                "task": {...}} -> annotations.json written atomically
    POST /api/calibrate        {"method": "board" | "plane", "edge": [[u, v], [u, v]] (optional: the table's
                                robot-side edge, left end then right end)} -> the camera pose found
                                (demoforge.lib.calibration) and written where the take keeps it

The pure logic (format, validation, back-projection, suggestion) is demoforge.lib.annotate; this module is glue.
"""

from __future__ import annotations

import json
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Callable
from urllib.parse import urlsplit

import numpy as np

import demoforge.lib  # PAGE is found from its folder
from demoforge.lib.annotate import (
    annotation_status, build_annotations, parse_task_section, point_info, suggest_closed_ranges, task_for_take,
    write_annotations,
)
from demoforge.lib.annotate.request_gate import MAX_BODY_BYTES, SAFE_METHODS, TOKEN_PARAM, RequestGate
from demoforge.lib.calibration import calibrate
from demoforge.lib.errors import UserError
from demoforge.lib.takes import TakeError, open_take, read_frame
from demoforge.lib.takes.pose import pose_file, write_pose
from demoforge.lib.task_library import TASK_NAMES
from demoforge.schemas.core import read_parquet_file, table_files
from demoforge.schemas.reads.per_hand import arrays

PAGE = Path(demoforge.lib.__file__).resolve().parent / "annotate" / "page.html"


class CalibrationMixin:
    """The page's calibration of a take without a pose (`demoforge calibrate` in the browser)."""

    def pose_state(self) -> dict:
        take = self.take
        return {"known": take.camera.T_world_camera is not None, "method": take.pose_method,
                "file": str(pose_file(take))}

    def calibrate(self, payload: dict) -> dict:
        if not isinstance(payload, dict):
            raise ValueError("the request body must be a JSON object")
        method = str(payload.get("method") or "auto")
        edge = payload.get("edge")
        if edge is not None:
            edge = np.asarray(edge, float)
            if edge.shape != (2, 2) or not np.isfinite(edge).all():
                raise ValueError("edge must be two [u, v] pixels: the robot-side table edge's left end, then its right end")
            method = "plane"
        result = calibrate(self.take, method=method, edge_clicks=edge)
        written = write_pose(self.take, result.T_world_camera, result.method, result.details)
        self.take = open_take(self.take.path, require_pose=False)
        T = result.T_world_camera
        return {"method": result.method, "details": result.details, "file": str(written),
                "T_world_camera": np.round(T, 6).tolist(), "pose": self.pose_state(),
                "summary": f"{result.method}: camera at ({T[0, 3]:+.3f}, {T[1, 3]:+.3f}, {T[2, 3]:+.3f}) m, "
                           f"written to {written}"}


class AnnotationSession(CalibrationMixin):
    """The take being annotated: frames and depth on demand (a few cached), the task, saving."""

    def __init__(self, take_dir: str | Path, warehouse: str | Path | None = None, task: str | None = None,
                 keypoints: str | None = None, task_file: str | Path | None = None):
        self.take = open_take(Path(take_dir).resolve(), require_pose=False)  # the page can calibrate it
        self.task = task_for_take(self.take, task, keypoints, task_file)
        self.warehouse = Path(warehouse) if warehouse is not None else None
        self.path = (self.take.meta_dir or self.take.path) / "annotations.json"  # a recording's: its side folder
        self._frames: OrderedDict[int, tuple[np.ndarray | None, np.ndarray]] = OrderedDict()
        self._lock = threading.Lock()

    # --- frames -----------------------------------------------------------------------------------
    def frame(self, index: int) -> tuple[np.ndarray | None, np.ndarray]:
        if not 0 <= index < self.take.n_frames:
            raise ValueError(f"frame {index} out of range: the take has {self.take.n_frames} frames")
        with self._lock:
            if index in self._frames:
                self._frames.move_to_end(index)
                return self._frames[index]
        got = read_frame(self.take, index)
        with self._lock:
            self._frames[index] = got
            while len(self._frames) > 16:
                self._frames.popitem(last=False)
        return got

    def frame_jpeg(self, index: int) -> bytes:
        import cv2

        rgb, _ = self.frame(index)
        if rgb is None:  # an unreadable frame: a grey image, the page says why
            rgb = np.full((self.take.camera.height, self.take.camera.width, 3), 96, np.uint8)
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise RuntimeError(f"frame {index}: JPEG encoding failed")
        return buf.tobytes()

    def points(self, frame: int, uv: Any) -> list[dict]:
        _, depth = self.frame(int(frame))
        pose = self.take.camera.T_world_camera
        out = point_info(np.asarray(uv, float).reshape(-1, 2), depth, self.take.K,
                         np.eye(4) if pose is None else pose)
        if pose is None:  # no table frame yet: camera-frame points only
            for p in out:
                p["world"] = None
        return out

    # --- ingest results ----------------------------------------------------------------------------
    def ingest_signals(self) -> dict | None:
        """Fingertip distance (T, 2) and the automatic closed ranges of the newest ingest, if any."""
        if self.warehouse is None:
            return None
        files = table_files("gripper_poses", self.warehouse, take=self.take.take_id)
        if not files:
            return None
        newest = max(files, key=lambda f: f.stat().st_mtime_ns)
        t = read_parquet_file(newest, "gripper_poses", ["frame", "hand", "fingertip_distance"])
        T, a = arrays(t, "fingertip_distance")
        d = a["fingertip_distance"].astype(float)
        return {"source": str(newest), "fingertip_distance": {s: [None if not np.isfinite(x) else round(float(x), 5)
                                                                  for x in d[:, h]]
                                                              for h, s in enumerate(("left", "right"))},
                "suggested_ranges": suggest_closed_ranges(d)}

    # --- state and saving --------------------------------------------------------------------------
    def state(self) -> dict:
        ann = self.take.annotations
        cam = self.take.camera
        signals = self.ingest_signals()
        current: dict[str, Any] = {"frame": 0, "points": {}, "ranges": None}
        if ann is not None:
            if ann.object_keypoints_frame is not None:
                current["frame"] = int(ann.object_keypoints_frame)
            current["points"] = {n: [float(u), float(v)] for n, (u, v)
                                 in zip(ann.object_keypoint_names, ann.object_keypoints_uv)
                                 if n in self.task.keypoint_names}
            if "gripper_closed_ranges" in ann.raw:
                current["ranges"] = {s: [list(r) for r in ann.gripper_closed_ranges.get(s, [])]
                                     for s in ("left", "right")}
        if current["ranges"] is None:  # nothing labelled yet: start from the automatic suggestion
            current["ranges"] = signals["suggested_ranges"] if signals else {"left": [], "right": []}
            current["ranges_from"] = "suggestion" if signals else "empty"
        else:
            current["ranges_from"] = "annotations.json"

        return {
            "take": self.take.take_id, "path": str(self.take.path), "n_frames": self.take.n_frames,
            "fps": self.take.fps, "width": cam.width, "height": cam.height,
            "frame_status": [f.status for f in self.take.frames],
            "annotations_file": str(self.path), "exists": self.path.is_file(),
            "status": annotation_status(self.take).__dict__,
            "pose": self.pose_state(),
            "task": self.task.to_json(), "library_tasks": list(TASK_NAMES),
            "current": current, "ingest": signals,
        }

    def save(self, payload: dict) -> dict:
        if not isinstance(payload, dict):
            raise ValueError("the request body must be a JSON object")
        task = parse_task_section(payload["task"], "task") if payload.get("task") else self.task
        if self.task.library and (task.name != self.task.name or task.keypoint_names != self.task.keypoint_names):
            raise ValueError(f"this is library task {self.task.name!r}: its name and keypoints are fixed")
        keep = self.take.annotations.raw if self.take.annotations is not None else None
        obj = build_annotations(task, payload.get("points") or {}, int(payload.get("frame", 0)),
                                payload.get("ranges") or {}, self.take.n_frames, keep=keep)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_annotations(self.path, obj)
        self.take = open_take(self.take.path, require_pose=False)  # re-read: what ingest will see
        self.task = task

        status = annotation_status(self.take)
        return {"saved": str(self.path), "annotations": obj, "status": status.__dict__}


@dataclass(frozen=True)
class Route:
    """One answer of the server: ``method`` and a ``pattern`` matched against the whole path;
    ``example`` is a path it matches (tests request every route). ``answer(session, match, body)``
    returns (status, body bytes, content type)."""

    method: str
    pattern: str
    example: str
    answer: Callable[[AnnotationSession, re.Match, Any], tuple[int, bytes, str]]

    def match(self, method: str, path: str) -> re.Match | None:
        return re.fullmatch(self.pattern, path) if method == self.method else None


def _json_reply(obj: Any, code: int = 200) -> tuple[int, bytes, str]:
    return code, json.dumps(obj).encode(), "application/json"


PAGE_ROUTE = Route("GET", r"/(index\.html)?", "/", lambda s, m, b: (200, PAGE.read_bytes(), "text/html; charset=utf-8"))
#: Every route the server answers. A request reaches one only after the RequestGate let it through.
ROUTES: tuple[Route, ...] = (
    PAGE_ROUTE,
    Route("GET", r"/api/state", "/api/state", lambda s, m, b: _json_reply(s.state())),
    Route("GET", r"/api/frame/(\d+)\.jpg", "/api/frame/0.jpg",
          lambda s, m, b: (200, s.frame_jpeg(int(m.group(1))), "image/jpeg")),
    Route("POST", r"/api/points", "/api/points",
          lambda s, m, b: _json_reply({"points": s.points(int(b.get("frame", 0)), b.get("uv", []))})),
    Route("POST", r"/api/save", "/api/save", lambda s, m, b: _json_reply(s.save(b))),
    Route("POST", r"/api/calibrate", "/api/calibrate", lambda s, m, b: _json_reply(s.calibrate(b))),
)
#: The most of a refused request's body the server reads (and drops) before it answers.
DISCARD_LIMIT = 16 * MAX_BODY_BYTES
#: Headers of every answer: no caching, no sniffing, never framed by another page, no Referer (the
#: page's URL carries the session token).
SECURITY_HEADERS = (("Cache-Control", "no-store"), ("X-Content-Type-Options", "nosniff"),
                    ("X-Frame-Options", "DENY"), ("Content-Security-Policy", "frame-ancestors 'none'"),
                    ("Referrer-Policy", "no-referrer"))


def make_handler(session: AnnotationSession, gate: RequestGate, routes: tuple[Route, ...] = ROUTES):
    """The request handler: every request, whatever its method and path, passes ``gate`` first."""
    class Handler(BaseHTTPRequestHandler):
        server_version = "demoforge-annotate"

        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002  (quiet: the page is the UI)
            pass

        def _send(self, code: int, body: bytes, ctype: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            for name, value in SECURITY_HEADERS:
                self.send_header(name, value)
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)

        def _refuse(self, code: int, reason: str, body_unread: bool = True) -> None:
            if body_unread:
                self._discard_body()
            self.close_connection = True  # a body left unread must not be taken for the next request
            self._send(*_json_reply({"error": reason}, code))

        def _discard_body(self) -> None:
            """Read a refused request's body (up to DISCARD_LIMIT), so the client gets to read the answer
            instead of a broken pipe."""
            length = self.headers.get("Content-Length", "")
            left = min(int(length), DISCARD_LIMIT) if length.strip().isdigit() else 0
            while left > 0 and (chunk := self.rfile.read(min(left, 1 << 16))):
                left -= len(chunk)

        def _handle(self) -> None:
            refusal = gate.check(self.command, self.path, self.headers)
            if refusal is not None:
                self._refuse(refusal.status, refusal.reason)
                return
            path = urlsplit(self.path).path
            found = next(((r, m) for r in routes if (m := r.match("GET" if self.command == "HEAD" else self.command,
                                                                    path)) is not None), None)
            if found is None:
                self._refuse(HTTPStatus.NOT_FOUND, f"no such page {self.command} {path}")
                return
            route, match = found
            body = None
            if self.command not in SAFE_METHODS:
                body = self.rfile.read(int(self.headers["Content-Length"]))  # the gate checked it
            try:
                self._send(*route.answer(session, match, None if body is None else json.loads(body or b"{}")))
            except (TakeError, UserError, ValueError, IndexError, KeyError, TypeError, AttributeError) as e:
                self._refuse(HTTPStatus.BAD_REQUEST, str(e), body_unread=False)  # JSONDecodeError is a ValueError
            except Exception as e:  # noqa: BLE001  (the page shows it; the server keeps running)
                self._refuse(HTTPStatus.INTERNAL_SERVER_ERROR, str(e), body_unread=False)

        do_GET = do_HEAD = do_POST = do_PUT = do_PATCH = do_DELETE = do_OPTIONS = _handle  # noqa: N815

    return Handler


class AnnotationServer(ThreadingHTTPServer):
    """The loopback server with its session's :class:`RequestGate` (``.gate.token`` is in :func:`server_url`)."""

    daemon_threads = True
    gate: RequestGate


def start_server(session: AnnotationSession, port: int = 0, host: str = "127.0.0.1",
                 token: str | None = None) -> AnnotationServer:
    """A loopback HTTP server for the session (port 0: any free port), with a new random token unless
    ``token`` is given; call serve_forever() on it."""
    server = AnnotationServer((host, port), BaseHTTPRequestHandler, bind_and_activate=True)
    server.gate = RequestGate(port=server.server_address[1], **({"token": token} if token else {}))
    server.RequestHandlerClass = make_handler(session, server.gate)
    return server


def server_url(server: AnnotationServer) -> str:
    """The page's URL with the session token (what the user opens)."""
    host, port = server.server_address[:2]
    return f"http://{host}:{port}/?{TOKEN_PARAM}={server.gate.token}"
