"""An interactive 3D head in a web page: the ``.glb`` of ``pipeline.face.gltf_export`` played by three.js
(vendored in ``lipsynth/web/three``, nothing loaded from the internet), with orbit controls, its
animation driven by the page's ``<audio>`` clock (``lipsynth/web/head_viewer.js``).

The page works opened from disk (file://), where browsers refuse to fetch module scripts and binary
files: the assets are classic scripts —

    <folder>/three-modules.js     window.LIPSYNTH_THREE_MODULES: the vendored modules' text (imported as blob: URLs)
    <folder>/head_viewer.js       the viewer
    <folder>/<stem>.glb.js        window.LIPSYNTH_GLB["<stem>"]: the .glb, base64
    <folder>/<stem>.wav           the audio (copied beside the .glb when it exists)
"""
from __future__ import annotations

import base64
import html
import json
import shutil
from pathlib import Path

from pipeline.errors import LipsynthError

# the lipsynth package's web assets (package data), found beside this package without importing lipsynth
# (pipeline imports no application): <root>/lipsynth/web in the checkout and in site-packages alike
WEB = Path(__file__).resolve().parents[2] / "lipsynth" / "web"
MODULES = ["three.core.js", "three.module.js", "BufferGeometryUtils.js", "SkeletonUtils.js", "GLTFLoader.js",
           "OrbitControls.js"]


def write_viewer_assets(folder, glb, width: int = 640, height: int = 480, rel: str = "") -> str:
    """Write the viewer's scripts and the head's data into ``folder``; returns the HTML to put in a page.

    Parameters
    ----------
    folder : str or Path
        Where the assets go (created).
    glb : str or Path
        The ``.glb`` (its ``.wav`` beside it, when present, is copied).
    width, height : int
        Canvas size (px).
    rel : str
        The folder's path relative to the page ("" when the page is in it).

    Returns
    -------
    str
        The HTML to put in the page.
    """
    glb = Path(glb)
    if not glb.is_file():
        raise LipsynthError(f"{glb}: no glTF head to show (write it with `lipsynth render-mesh --glb`)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    three = {name: (WEB / "three" / name).read_text() for name in MODULES}
    (folder / "three-modules.js").write_text("window.LIPSYNTH_THREE_MODULES = " + json.dumps(three) + ";\n")
    shutil.copyfile(WEB / "head_viewer.js", folder / "head_viewer.js")
    shutil.copyfile(WEB / "three" / "LICENSE", folder / "three.js.LICENSE")
    stem = glb.stem
    b64 = base64.b64encode(glb.read_bytes()).decode("ascii")
    (folder / f"{stem}.glb.js").write_text(
        f"window.LIPSYNTH_GLB = window.LIPSYNTH_GLB || {{}};\nwindow.LIPSYNTH_GLB[{json.dumps(stem)}] = \"{b64}\";\n")
    wav = glb.with_suffix(".wav")
    if wav.is_file() and wav.resolve() != (folder / wav.name).resolve():
        shutil.copyfile(wav, folder / wav.name)
    return viewer_html(stem, wav.name if wav.is_file() else None, width, height, rel)


def viewer_html(stem: str, audio: str | None, width: int = 640, height: int = 480, rel: str = "") -> str:
    """The page's markup for a head whose assets ``write_viewer_assets`` wrote (pure: no file access).

    Parameters
    ----------
    stem : str
        The ``.glb``'s stem (its data script is ``<rel><stem>.glb.js``).
    audio : str or None
        The audio file's name in the assets folder (None: no audio player; the head stays at frame 0).
    width, height : int
        Canvas size (px).
    rel : str
        The assets folder's path relative to the page.

    Returns
    -------
    str
        A ``div.lipsynth-head`` (canvas + audio) and the three scripts.
    """
    e = html.escape
    player = f"<audio controls preload=\"auto\" src=\"{e(rel + audio)}\"></audio>" if audio else ""
    return (f"<div class=\"lipsynth-head\" data-glb=\"{e(stem)}\">"
            f"<canvas width=\"{width}\" height=\"{height}\" style=\"display:block;touch-action:none\"></canvas>"
            f"{player}</div>"
            f"<script src=\"{e(rel)}three-modules.js\"></script><script src=\"{e(rel + stem)}.glb.js\"></script>"
            f"<script src=\"{e(rel)}head_viewer.js\"></script>")


def write_viewer_page(glb, page=None, title: str = "lipsynth 3D head", width: int = 640, height: int = 480) -> Path:
    """A standalone page playing ``glb`` (default: ``<stem>.html`` beside it, its assets beside it too)."""
    glb = Path(glb)
    page = Path(page) if page else glb.with_suffix(".html")
    body = write_viewer_assets(page.parent, glb, width, height)
    page.write_text(f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}"
                    f"</title></head><body style=\"background:#111;color:#ddd;font-family:sans-serif\">"
                    f"<p>Drag to orbit, scroll to zoom; play the audio to animate.</p>{body}</body></html>\n")
    return page
