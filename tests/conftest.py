import os
from pathlib import Path

# `pytest -n 2` runs two test processes that each drive torch on both cores (the demo's dvc repro beside the GRID
# model's training): OpenMP's idle threads then spin and take the cores from the other process. Measured on
# Karras' training step (2 cores): 0.8 s alone, 2.2 s each with two at once, 1.3 s each with passive waiting,
# which changes no result (the work and its split are the same). Set before torch loads; stage subprocesses inherit it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import cv2
import pytest
import skimage.data

from pipeline.face import dlib_face
from stages.frontalize import model3d

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LIPSYNTH_SHARED_DATA", ROOT.parent / "shared" / "data"))


def skip_unless_ci(reason: str):
    """Skip the test for ``reason`` (a tool or data this machine lacks) — except in CI (``.ci/run`` sets
    LIPSYNTH_CI=1 after installing everything), where a missing tool fails the test: no test may skip
    on every CI run."""
    if os.environ.get("LIPSYNTH_CI"):
        pytest.fail(f"{reason} — CI must provide it (.ci/run)")
    pytest.skip(reason, allow_module_level=True)


def shared(*parts) -> Path:
    """Path into ../shared/data; skips the test with a clear reason when it is absent (fails in CI)."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        skip_unless_ci(f"real footage not available: {p} is absent (CI provides ../shared/data)")
    return p


# the longest modules first (each runs in one process under ``-n 2``: a module's fixture is built once), so the
# two processes finish together instead of one starting the longest module when the other is nearly done
LONGEST_FIRST = ("test_speak_held_out.py", "test_dvc_pipeline.py", "test_determinism.py", "test_dask_cluster.py")


def pytest_collection_modifyitems(items):
    order = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: order.get(item.path.name, len(order)))       # stable: the rest keep file order


@pytest.fixture(autouse=True)
def _project_cwd(monkeypatch):
    monkeypatch.chdir(ROOT)


@pytest.fixture(scope="session")
def face3d():
    """A realistic 68-point model: dlib landmarks of a real photo + the anthropometric depth prior."""
    photo = skimage.data.astronaut()
    gray = cv2.cvtColor(photo, cv2.COLOR_RGB2GRAY)
    box, _ = dlib_face.detect_faces(gray)[0]
    mean2d = model3d.mean_shape_2d(dlib_face.predict_landmarks(gray, box)[None].astype(float))
    return model3d._to_canonical(model3d.prior_shape(mean2d))


@pytest.fixture(scope="session")
def grid_preprocessed(tmp_path_factory):
    """12 GRID s1 clips through ingest → landmarks → frontalize (once per session): its folder
    holds ingest.zarr, landmarks.zarr, frontalize.zarr and params.yaml."""
    from tests.helpers.stages import make_params, run_preprocessing
    clips = sorted(shared("grid_s1", "video").glob("*.mp4"))[:12]
    out = tmp_path_factory.mktemp("grid12")
    run_preprocessing(make_params(out, [str(c) for c in clips]))
    return out
