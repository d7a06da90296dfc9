"""``lipsynth live --serve``: a local web page that plays the live HLS stream with its sound.

The page (``lipsynth/web/index.html``) plays ``stream/index.m3u8`` with hls.js (vendored from the npm
registry into ``lipsynth/web/``: nothing loads from the internet) and shows the clock and the tracks it
found. The server answers on 127.0.0.1 only: ``/`` the page, ``/hls.light.min.js`` the player,
``/stream/…`` the HLS folder ``live`` writes.
"""
from __future__ import annotations

import functools
import logging
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

log = logging.getLogger("lipsynth.live")
WEB = Path(__file__).resolve().parent / "web"


class PageHandler(SimpleHTTPRequestHandler):
    def __init__(self, *args, stream_dir: Path, **kwargs):
        self.stream_dir = stream_dir
        super().__init__(*args, directory=str(WEB), **kwargs)

    def translate_path(self, path: str) -> str:
        clean = path.split("?", 1)[0].split("#", 1)[0]
        if clean.startswith("/stream/"):
            name = Path(clean[len("/stream/"):]).name          # the folder's own files, no other path
            return str(self.stream_dir / name)
        return super().translate_path(path)

    def do_GET(self):
        if self.path == "/favicon.ico" or (self.path.startswith("/stream/index.m3u8")
                                           and not (self.stream_dir / "index.m3u8").is_file()):
            self.send_response(204)                              # not yet (the page polls) / no icon
            self.end_headers()
            return
        super().do_GET()

    def end_headers(self):
        self.send_header("Cache-Control", "no-store")            # the playlist grows while it plays
        super().end_headers()

    def log_message(self, fmt, *args):                          # requests at debug level, not on stderr
        log.debug("page: " + fmt, *args)


def serve(stream_dir: Path, port: int = 0) -> ThreadingHTTPServer:
    """Start serving the page and ``stream_dir`` on 127.0.0.1:``port`` (0: a free port) in a thread."""
    server = ThreadingHTTPServer(("127.0.0.1", port), functools.partial(PageHandler, stream_dir=stream_dir))
    threading.Thread(target=server.serve_forever, daemon=True, name="live-page").start()
    log.info("serving http://127.0.0.1:%d/ — the page plays the stream with its sound (Ctrl-C stops)",
                server.server_address[1])
    return server
