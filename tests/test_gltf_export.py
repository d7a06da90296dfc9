"""The animated head as glTF 2.0 (``pipeline.face.gltf_export``) and its web viewer
(``pipeline.face.gltf_viewer``, ``lipsynth/web/head_viewer.js``): the Khronos validator finds no error,
three.js plays it with the mouth moving, the viewer follows the audio clock, a bad path is one line."""
import json
import re
import time

import numpy as np
import pytest

from pipeline.errors import LipsynthError
from pipeline.face import face_mesh, gltf_export, gltf_viewer
from pipeline.face import head_mesh as hm
from pipeline.face.head_texture import HeadWindow
from pipeline.params import Params
from stages.frontalize.frontalize import build_surface
from tests.helpers.gltf_validator import validate

FPS, T = 25.0, 150          # 6 s: the viewer is checked at 5 s of audio
LOWER = list(range(55, 60)) + [65, 66, 67]


@pytest.fixture(scope="module")
def animated(face3d):
    """(rest HeadMesh, HeadMotion: the jaw opening 0–12 mm once a second, red/blue texture, 16 kHz tone)."""
    surface = hm.smooth_surface(build_surface(face3d, Params().frontalize)[0])
    window = HeadWindow.covering(1.0)
    lm = face3d[:, :2].astype(np.float64)
    lm[[67, 66, 65]] = lm[[61, 62, 63]] + [0.0, 0.5]
    mesh = hm.head_mesh(surface, window, lm, 2.0)
    ids = list(range(48, 68))
    moved = np.repeat(lm[ids][None], T, 0)
    moved[:, [ids.index(i) for i in LOWER], 1] += 6 * (1 - np.cos(2 * np.pi * np.arange(T) / FPS))[:, None]
    motion = face_mesh.animate(mesh, surface, lm, ids, moved)
    tex = np.zeros((window.height, window.width, 3), np.uint8)
    tex[: window.height // 2], tex[window.height // 2:] = (200, 60, 60), (60, 60, 200)
    samples = 0.2 * np.sin(2 * np.pi * 220 * np.arange(int(T / FPS * 16000)) / 16000)
    return mesh, motion, tex, samples


@pytest.fixture(scope="module")
def glb(animated, tmp_path_factory):
    mesh, motion, tex, samples = animated
    path = tmp_path_factory.mktemp("glb") / "head.glb"
    figures = gltf_export.write_glb(path, mesh, motion, tex, FPS, samples)
    return path, figures


def test_morph_targets_reproduce_every_frame(animated):
    mesh, motion, _, _ = animated
    rest, frames = mesh.skin.vertices * 1e-3, motion.skin * 1e-3
    anim = gltf_export.morph_animation(rest, frames, mesh.skin.triangles, tol_mm=0.05)
    back = rest + np.einsum("tk,kmc->tmc", anim.weights, anim.deltas)
    assert anim.deltas.shape[0] <= 64 and anim.max_error_mm <= 0.05
    assert np.abs(back - frames).max() * 1e3 <= 0.06                 # float32 rounding on top
    still = gltf_export.morph_animation(rest, np.repeat(rest[None], 5, 0), mesh.skin.triangles)
    assert still.max_error_mm == 0 and np.all(still.weights == 0)


def test_glb_passes_the_khronos_validator_with_its_audio_beside(glb):
    path, figures = glb
    report = validate(path)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    info = report["info"]
    assert info["animationCount"] == 1 and info["hasMorphTargets"] and info["hasTextures"]
    assert figures["frames"] == T and figures["max_error_mm"] <= 0.1
    assert path.with_suffix(".wav").is_file() and not list(path.parent.glob(".*tmp*"))
    import pygltflib
    g = pygltflib.GLTF2.load(str(path))
    w = g.accessors[g.animations[0].samplers[0].output]
    assert w.min[0] >= 0 and w.max[0] <= 1                             # Blender clamps shape keys to 0–1


def test_an_unwritable_glb_path_is_one_line_and_nothing_is_written(animated, tmp_path):
    mesh, motion, tex, samples = animated
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for bad in (blocker / "head.glb", blocker / "a" / "head.glb", tmp_path / "head.obj", tmp_path):
        with pytest.raises(LipsynthError) as e:
            gltf_export.write_glb(bad, mesh, motion, tex, FPS, samples)
        assert "\n" not in str(e.value) and str(bad) in str(e.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def _open_viewer(dt, s, timeout=90.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        st = dt.evaluate(s, "JSON.stringify({r: (window.lipsynthViewers || []).map(v => v.ready),"
                            " e: window.lipsynthViewerError || null})")
        st = json.loads(st)
        assert st["e"] is None, st["e"]
        if st["r"] and all(st["r"]):
            return
        time.sleep(0.3)
    pytest.fail("the 3D viewer did not load within 90 s")


def play_and_check(page, tmp_path) -> None:
    """Open ``page`` in headless Chromium: three.js's AnimationMixer moves the mouth, the canvas is drawn,
    and, playing, the picture changes and the pose on screen is within one frame of the audio clock at 5 s."""
    from tests.helpers.browser import page_errors, page_session, screenshot
    with page_session(page.absolute().as_uri(), tmp_path / "chromium-profile") as (dt, s):
        _open_viewer(dt, s)
        v = "window.lipsynthViewers[0]"
        # AnimationMixer at a shut (t = 0) and an open (t = 0.5 s) frame: some skin vertex moves > 5 mm
        moved = dt.evaluate(s, f"""(() => {{ const v = {v}; let best = 0;
            for (let i = 0; i < 6000; i += 7) {{ const a = v.vertexAt(0, i), b = v.vertexAt(0.5, i);
              if (isNaN(a[0])) break; best = Math.max(best, Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2])); }}
            return best; }})()""")
        assert moved > 0.005, moved                                     # metres
        first = np.array(dt.evaluate(s, f"{v}.snapshot()"), float).reshape(64, 64, 4)
        assert first[..., :3].std() > 10                                # drawn: not a blank canvas
        dt.evaluate(s, f"{v}.audio.play()")
        waited, changed = time.monotonic(), 0.0
        while dt.evaluate(s, f"{v}.audio.currentTime") < 5.0:       # the picture while it plays, every ~0.3 s
            assert time.monotonic() - waited < 60, "the audio did not play"
            shot = np.array(dt.evaluate(s, f"{v}.snapshot()"), float).reshape(64, 64, 4)
            changed = max(changed, np.abs(shot - first).max())
            time.sleep(0.3)
        # at each of 10 frames from 5 s on, read in the animation frame that drew it: the pose's time on
        # screen against the audio clock (a slow software GL draws ~15 frames/s; the gap is not left to grow)
        sync = dt.evaluate(s, f"""(async () => {{ const v = {v}, out = [];
            for (let i = 0; i < 10; i++) {{ await new Promise(r => requestAnimationFrame(r));
              out.push([v.audio.currentTime, v.shownTime]); }} return out; }})()""")
        frames = dt.evaluate(s, f"{v}.frames")
        screenshot(dt, s, tmp_path / "viewer.png")
        errors = page_errors(dt)
    gap = np.abs(np.diff(np.array(sync), axis=1))
    assert gap.max() <= 1 / FPS, sync                                  # within one frame of the audio clock
    assert frames > 10
    assert changed > 30                                                # the picture changed as it played
    assert errors == [], errors


def test_three_js_plays_the_glb_with_the_mouth_moving_and_follows_the_audio(glb, tmp_path):
    page = gltf_viewer.write_viewer_page(glb[0], tmp_path / "viewer" / "head.html", width=320, height=240)
    play_and_check(page, tmp_path)


def test_the_report_page_shows_the_head_in_sync_with_its_audio(glb, tmp_path):
    import shutil
    from stages.report import report
    from tests.test_report import write_fixture_project
    pfile, tree = write_fixture_project(tmp_path)
    folder = tmp_path / "head"                                         # the render_mesh stage's export folder
    folder.mkdir()
    for f in (glb[0], glb[0].with_suffix(".wav")):
        shutil.copyfile(f, folder / f.name)
    page = report.write_report(report.load_params(pfile), pfile)
    text = page.read_text()
    assert text.count('class="lipsynth-head"') == 1 and 'src="head/head.wav"' in text
    assert not re.search(r'(src|href)="(https?:)?//', text)            # nothing from the internet
    play_and_check(page, tmp_path)
