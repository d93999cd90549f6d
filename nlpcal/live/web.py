"""The web view of a live calibration: a page on 127.0.0.1, served by nlpcal alone.

`WebView` runs the standard library's HTTP server in a thread, bound to the loopback interface
only. It serves the page (`static/live.html`: plain JavaScript and canvas, nothing fetched from
elsewhere) and `/state`, the latest update with the corrected point cloud and its residuals and
the grid's cell centres, which the page polls twice a second.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib.resources import files

from ..errors import InputError
from ..io.files import plain
from .grid import cell_centres, zones
from .session import Update

#: The only interface the view listens on.
HOST = "127.0.0.1"


class WebView:
    """The server; `publish` hands it each update. port : 0 takes any free one."""

    def __init__(self, port: int):
        self._lock = threading.Lock()
        self._state = json.dumps({"n_samples": 0, "waiting": True}).encode()
        self._page = files("nlpcal.live").joinpath("static/live.html").read_bytes()
        view = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):
                if self.path.split("?")[0] == "/state":
                    with view._lock:
                        body, kind = view._state, "application/json"
                elif self.path in ("/", "/index.html"):
                    body, kind = view._page, "text/html; charset=utf-8"
                else:
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args):  # no request log on stderr
                return

        try:
            self.server = ThreadingHTTPServer((HOST, port), Handler)
        except OSError as error:
            raise InputError(f"--web-port {port}: cannot listen there ({error.strerror})") from None
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.server.server_address[1]}/"

    def publish(self, update: Update, cloud: dict) -> None:
        """Make `update` and its cloud (`LiveSession.cloud`) the state the page shows."""
        counts, _, _ = zones()
        state = {
            **update.to_dict(),
            "cloud": cloud,
            "grid": {"zones": counts, "centres": cell_centres()},
        }
        body = json.dumps(plain(state), allow_nan=False).encode()
        with self._lock:
            self._state = body

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
