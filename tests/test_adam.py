"""pipeline.models.adam: PyTorch's Adam update, with bits that do not depend on Intel MKL's vector-math branch."""
import json
import os
import subprocess
import sys

import torch

from pipeline.models.adam import adam
from tests.conftest import ROOT

STEPS = ("import hashlib, json, sys; sys.path.insert(0, {root!r})\n"
         "import pipeline, torch\n"
         "from pipeline.models.adam import adam\n"
         "out = {{}}\n"
         "for name, make in (('fused', lambda p: adam(p, 1e-3)), ('default', lambda p: torch.optim.Adam(p, lr=1e-3))):\n"
         "    torch.manual_seed(0)\n"
         "    w = torch.nn.Parameter(torch.randn(4000))\n"
         "    opt = make([w])\n"
         "    for _ in range(3):\n"
         "        opt.zero_grad(); ((w - 0.5) ** 2 * torch.linspace(0.1, 3, 4000)).sum().backward(); opt.step()\n"
         "    out[name] = hashlib.sha256(w.detach().numpy().tobytes()).hexdigest()\n"
         "print(json.dumps(out))\n")


def weights_under(branch: str) -> dict:
    env = dict(os.environ, MKL_CBWR=branch)
    done = subprocess.run([sys.executable, "-c", STEPS.format(root=str(ROOT))], env=env, capture_output=True,
                          text=True, check=True)
    return json.loads(done.stdout)


def test_adam_is_torchs_update():
    torch.manual_seed(0)
    a, b = torch.nn.Parameter(torch.randn(300)), None
    b = torch.nn.Parameter(a.detach().clone())
    opts = adam([a], 3e-3), torch.optim.Adam([b], lr=3e-3)
    for step in range(5):
        for w, opt in zip((a, b), opts):
            opt.zero_grad()
            ((w - 0.2 * step) ** 2).sum().backward()
            opt.step()
    assert not torch.equal(a, torch.zeros_like(a))
    torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_adams_bits_do_not_follow_mkls_branch():
    """Intel MKL's SSE2 branch (what the cap selects, the vendor-neutral one) and its own pick on the CPU
    can give torch.sqrt other last bits — on an Intel CPU they do, and the default Adam's weights then
    differ (what made the training stages differ between CPU makers). The fused Adam's weights are the
    same bits under every branch MKL_CBWR asks for. (On an AMD EPYC MKL runs one branch whatever
    MKL_CBWR asks, so only the fused Adam's agreement can be shown there; this checks it everywhere.)"""
    runs = {branch: weights_under(branch) for branch in ("COMPATIBLE", "AUTO", "AVX2", "SSE4_2")}
    fused = {branch: r["fused"] for branch, r in runs.items()}
    assert len({json.dumps(v) for v in fused.values()}) == 1, fused
