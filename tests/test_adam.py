"""pipeline.models.adam: PyTorch's Adam update, with bits that do not depend on Intel MKL's vector-math branch."""
import json
import os
import subprocess
import sys

import pytest
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
    """Intel MKL's SSE2 branch (what the cap selects, the vendor-neutral one) and its own pick on this CPU
    give torch.sqrt other last bits — so the default Adam's weights differ (the precondition: what made the
    training stages differ between CPU makers) — while the fused Adam's do not."""
    compatible, auto = weights_under("COMPATIBLE"), weights_under("AUTO")
    assert compatible["fused"] == auto["fused"]
    if compatible["default"] == auto["default"]:
        # an AMD EPYC (this stop's machine): MKL runs one branch whatever MKL_CBWR asks (COMPATIBLE, AUTO, AVX2
        # and SSE4_2 gave the same bits), so the precondition cannot be shown on this CPU
        pytest.skip("MKL takes the same branch at every MKL_CBWR on this CPU (not an Intel one): the default "
                    "Adam cannot differ here, only the fused one's agreement is checked")
