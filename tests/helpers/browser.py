"""Open a page in headless Chromium over the DevTools protocol: its videos, plots and console errors."""
import base64
import contextlib
import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from tests.conftest import skip_unless_ci


def chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        skip_unless_ci("chromium not installed (Debian package `chromium`; .ci/run installs it when it can)")
    return exe


class DevTools:
    """A minimal Chrome DevTools protocol client over one websocket (flat sessions)."""

    def __init__(self, url: str):
        import websocket
        self.ws = websocket.create_connection(url, timeout=60, suppress_origin=True)
        self.next_id, self.events = 0, []

    def call(self, method: str, session: str | None = None, **params):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        self.ws.send(json.dumps(msg))
        while True:
            r = json.loads(self.ws.recv())
            if r.get("id") == self.next_id:
                if "error" in r:
                    raise RuntimeError(f"{method}: {r['error']}")
                return r.get("result", {})
            self.events.append(r)

    def evaluate(self, session: str, expression: str):
        r = self.call("Runtime.evaluate", session, expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression[:60]}…: {r['exceptionDetails']}")
        return r["result"].get("value")


CHECKS = """(() => ({
  ready: document.readyState,
  videos: [...document.querySelectorAll('video')].map(v => ({src: v.getAttribute('src'), readyState: v.readyState,
      duration: v.duration, expected: parseFloat(v.dataset.duration), error: v.error && v.error.code})),
  svgs: [...document.querySelectorAll('svg')].map(s => {const r = s.getBoundingClientRect();
      return {children: s.querySelectorAll('path,line,text,use').length, width: r.width, height: r.height};}),
}))()"""


@contextlib.contextmanager
def page_session(url: str, profile: Path):
    """Headless Chromium on ``url``: yields (DevTools client, session id); closes the browser after."""
    pytest.importorskip("websocket", reason="websocket-client (test extra) drives Chromium")
    proc = subprocess.Popen([chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                             "--disable-background-networking", "--disable-component-update", "--disable-sync",
                             "--remote-debugging-port=0", f"--user-data-dir={profile}", "--window-size=1280,900",
                             "--autoplay-policy=no-user-gesture-required", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        port_file = profile / "DevToolsActivePort"
        for _ in range(300):
            if port_file.is_file() and len(port_file.read_text().split()) >= 2:
                break
            time.sleep(0.1)
        else:
            pytest.fail("chromium did not open its DevTools port within 30 s")
        port, path = port_file.read_text().split()[:2]
        dt = DevTools(f"ws://127.0.0.1:{port}{path}")
        target = dt.call("Target.createTarget", url="about:blank")["targetId"]
        s = dt.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            dt.call(f"{domain}.enable", s)
        dt.call("Page.navigate", s, url=url)
        yield dt, s
        dt.call("Browser.close")
    finally:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def screenshot(dt: DevTools, s: str, shot: Path) -> None:
    size = dt.call("Page.getLayoutMetrics", s)["cssContentSize"]
    png = dt.call("Page.captureScreenshot", s, format="png", captureBeyondViewport=True,
                  clip={"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1})["data"]
    shot.write_bytes(base64.b64decode(png))


def page_errors(dt: DevTools) -> list:
    return [e["params"] for e in dt.events if e.get("method") == "Runtime.exceptionThrown"
            or (e.get("method") == "Runtime.consoleAPICalled" and e["params"].get("type") == "error")
            or (e.get("method") == "Log.entryAdded" and e["params"]["entry"].get("level") == "error")]


def check_in_browser(page: Path, shot: Path) -> dict:
    with page_session(page.absolute().as_uri(), shot.parent / "chromium-profile") as (dt, s):
        deadline = time.monotonic() + 60
        while True:
            state = dt.evaluate(s, CHECKS)
            loaded = state["ready"] == "complete" and all(v["readyState"] >= 3 or v["error"] for v in state["videos"])
            if loaded or time.monotonic() > deadline:
                break
            time.sleep(0.25)
        time.sleep(0.5)                  # let the media controls drop their loading spinner
        state = dt.evaluate(s, CHECKS)
        screenshot(dt, s, shot)
        return dict(state, errors=page_errors(dt))


def assert_page_renders(state: dict, n_videos: int, n_svgs: int) -> None:
    assert state["errors"] == [], state["errors"]
    assert len(state["videos"]) == n_videos
    for v in state["videos"]:
        assert v["readyState"] >= 2, f"{v['src']}: readyState {v['readyState']} (media error {v['error']})"
        assert v["duration"] == pytest.approx(v["expected"], abs=0.1), v
    assert len(state["svgs"]) == n_svgs
    for s in state["svgs"]:
        assert s["children"] > 10 and s["width"] > 100 and s["height"] > 50, s
