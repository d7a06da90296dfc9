"""The Khronos glTF validator (npm ``gltf-validator``) run under node: installed once into a cache folder."""
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

VERSION = "2.0.0-dev.3.10"
SCRIPT = ("const v = require('gltf-validator'); const fs = require('fs');"
          "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[1])), {maxIssues: 100})"
          ".then(r => console.log(JSON.stringify(r))).catch(e => { console.error(String(e)); process.exit(2); });")


def tools_dir() -> Path:
    return Path(os.environ.get("LIPSYNTH_NODE_TOOLS", Path.home() / ".cache" / "lipsynth" / "node-tools"))


def validate(glb: Path) -> dict:
    """The validator's report of ``glb`` (its ``issues`` hold numErrors, numWarnings, messages)."""
    node = shutil.which("node")
    if node is None:
        from tests.conftest import skip_unless_ci
        skip_unless_ci("node not installed: the Khronos glTF validator runs under node")
    tools = tools_dir()
    if not (tools / "node_modules" / "gltf-validator" / "package.json").is_file():
        npm = shutil.which("npm")
        if npm is None:
            pytest.fail("node is installed but npm is not: cannot install gltf-validator")
        tools.mkdir(parents=True, exist_ok=True)
        subprocess.run([npm, "install", "--prefix", str(tools), "--no-audit", "--no-fund", "--silent",
                        f"gltf-validator@{VERSION}"], check=True, timeout=600)
    r = subprocess.run([node, "-e", SCRIPT, str(Path(glb).absolute())], cwd=tools, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)
