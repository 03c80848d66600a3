"""A real OpenAI-compatible HTTP server on 127.0.0.1 with scripted answers, the openai backend pointed at it,
and a small prompt to send it."""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np

from demoforge.lib.llm.openai_backend import OpenAIBackend
from demoforge.lib.llm.prompting import build_prompt


SECRET = "sk-test-DO-NOT-LEAK-4242"


class FakeOpenAIServer:
    """Scripted answers, one per request: ("ok", text, usage|None) / ("sleep", seconds) /
    ("status", code, body).  The last entry repeats.  Requests are recorded."""

    def __init__(self):
        self.script: list[tuple] = [("ok", "[[[0,0,0,0,0,0,1,1],[0,0,0,0,0,0,1,1]]]", None)]
        self.requests: list[dict] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # keep test output quiet
                pass

            def do_POST(self):
                n = int(self.headers.get("Content-Length", 0))
                body = json.loads(self.rfile.read(n) or b"{}")
                i = len(outer.requests)
                outer.requests.append({"path": self.path, "body": body, "headers": dict(self.headers)})
                step = outer.script[min(i, len(outer.script) - 1)]
                try:
                    if step[0] == "sleep":
                        time.sleep(step[1])
                        self._json(200, outer._answer("late", None, body))
                    elif step[0] == "status":
                        payload = step[2].replace("{auth}", self.headers.get("Authorization", "")).encode()
                        self.send_response(step[1])
                        self.send_header("Content-Type", "application/json")
                        self.send_header("Content-Length", str(len(payload)))
                        self.end_headers()
                        self.wfile.write(payload)
                    else:
                        self._json(200, outer._answer(step[1], step[2], body))
                except (BrokenPipeError, ConnectionResetError):
                    pass

            def _json(self, code, obj):
                data = json.dumps(obj).encode()
                self.send_response(code)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05},
                                       daemon=True)
        self.thread.start()

    @staticmethod
    def _answer(text, usage, body):
        choice = {"index": 0, "finish_reason": "stop"}
        if "messages" in body:
            choice["message"] = {"role": "assistant", "content": text}
        else:
            choice["text"] = text
        out = {"id": "x", "object": "chat.completion", "model": body.get("model"), "choices": [choice]}
        if usage is not None:
            out["usage"] = usage
        return out

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


def small_prompt(shift=0.0, n_examples=1):
    rng = np.random.default_rng(0)
    kp = rng.uniform(-0.3, 0.3, size=(11, 3)) + shift
    acts = np.zeros((6, 2, 8))
    acts[:, :, :3] = np.linspace(0, 0.1, 6)[:, None, None] + np.array([[-0.2, 0.1, 0.15], [0.2, 0.1, 0.15]])
    acts[:, :, 6] = 1.0
    acts[:, :, 7] = 1.0
    acts[3:, 1, 7] = 0.0
    ex = (kp, acts[0], acts)
    return build_prompt([ex] * n_examples, kp + 0.01, acts[0], n_waypoints=4)


def openai_backend(server, **kw):
    """The openai backend talking to ``server`` (with SECRET as its key)."""
    opts = dict(model="test-model", base_url=server.url, api_key=SECRET, timeout_s=5, max_retries=2,
                backoff_s=0.01)
    opts.update(kw)
    return OpenAIBackend(**opts)
