import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("LIPSYNTH_SHARED_DATA", ROOT.parent / "shared" / "data"))


def shared(*parts) -> Path:
    """Path into ../shared/data; skips the test with a clear reason when it is absent."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real footage not available: {p} is absent (CI provides ../shared/data)")
    return p


@pytest.fixture(autouse=True)
def _project_cwd(monkeypatch):
    monkeypatch.chdir(ROOT)
