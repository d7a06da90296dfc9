"""Training loop of Karras et al. 2017 (paper 001 §4): temporal pairs, a learned emotion per
training frame, on-the-fly autocorrelation windows with time-shift augmentation, the
self-normalising three-term loss, and the paper's Adam schedule.

``fit(videos, config)`` takes per-video dicts (``targets.load_targets``: samples, frame_time,
targets (T, D), ok, split) and returns the trained network, the emotion database and the history.
Everything random draws from ``config.seed``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from pipeline.models.adam import adam
from pipeline.models.karras_network import KarrasNetwork
from pipeline.audio.speech_autocorrelation import padded_track, windows
from pipeline.models.training_budget import Budget, EarlyStopping, StepPlan
from stages.train_karras import objective
from stages.train_karras.targets import training_pairs

log = logging.getLogger("lipsynth.train_karras")


@dataclass
class FitConfig:
    steps: int = 12000              # optimizer steps (500 epochs of 1,200 frames = the paper's schedule, §4.5)
    batch: int = 100                # 50 temporal pairs (§4.5)
    lr: float = 1e-3
    emotion_dim: int = 16
    emotion_sigma: float = 0.01
    motion: bool = True             # ablations: the motion term, the emotion database, time shifts
    emotions: bool = True
    time_shift: bool = True
    seed: int = 0
    device: str = "cpu"
    val_every: int = 100            # steps between validation points (on_validation is called there)
    patience: int | None = None     # validation points without improvement before stopping (None: never)
    min_delta: float = 0.0


def target_pca(y: np.ndarray, k: int = 150) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and up to ``k`` principal components (k', D) of the training targets (§3.1)."""
    mean = y.mean(0)
    _, _, vt = np.linalg.svd(y - mean, full_matrices=False)
    return mean, vt[:k]


def batch_inputs(videos, rows: np.ndarray, shifts: np.ndarray):
    """Autocorrelation windows (B, 1, 64, 32) and shifted targets (B, D) for (video, frame) rows."""
    x, y = [], []
    for (vi, fi), s in zip(rows, shifts):
        v = videos[vi]
        if "padded" not in v:
            v["padded"] = padded_track(v["samples"], v.get("name", "audio"))
        t = np.array([v["frame_time"][fi] + s])
        x.append(windows(v["padded"], t)[0])
        y.append(objective.shifted_targets(v["targets"], v["frame_time"], t)[0])
    return np.stack(x)[:, None], np.stack(y)


def minibatch(train: list[dict], pairs: np.ndarray, config: FitConfig, rng: np.random.Generator):
    """One minibatch of temporal ``pairs`` (P, 2) (video, first frame): its rows (2P, 2) (video, frame), the
    autocorrelation windows (2P, 1, 64, 32) on ``config.device`` (channels last), time-shifted with ``rng``
    when ``config.time_shift``, and their shifted targets (2P, D)."""
    rows = np.repeat(pairs, 2, 0)
    rows[1::2, 1] += 1                                      # the pair's second frame
    shifts = objective.pair_shifts(len(pairs), rng) if config.time_shift else np.zeros(len(rows))
    x, y = batch_inputs(train, rows, shifts)
    return rows, torch.as_tensor(x, device=config.device).contiguous(memory_format=torch.channels_last), y


def fit(videos: list[dict], config: FitConfig, progress: bool = True, on_validation=None, log_plan=None):
    """Train on the ``train`` videos for ``config.steps`` optimizer steps; returns (network,
    emotions (N, E) — one per frame of the training videos, in their order — and the history: per
    validation point (every ``config.val_every`` steps and at the end) the step, the epoch (an
    epoch: as many samples as training frames) and the mean raw loss terms since the previous
    point, plus whatever ``on_validation(step, net, emotions)`` returns (e.g. validation figures; its
    ``val_position`` drives early stopping when ``config.patience`` is set: the network and the
    emotions of the best point are returned)). The paper's schedule (§4.5) is stretched over the
    budget: the learning-rate ramp-up over the first epoch, 1/√epoch decay, the ramp-down at the end."""
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    budget = Budget(config.steps, config.val_every, config.patience, config.min_delta).check("karras")
    train = [v for v in videos if v["split"] == "train"]
    pairs = training_pairs(train)
    if len(pairs) < config.batch:
        raise ValueError(f"{len(pairs)} training pairs are fewer than one minibatch ({config.batch // 2})")
    ys = np.concatenate([v["targets"][v["ok"]] for v in train])
    mean, comps = target_pca(ys)
    net = KarrasNetwork(ys.shape[1], config.emotion_dim).to(config.device)
    net.init_output_from_pca(mean, comps)
    net = net.to(memory_format=torch.channels_last)       # NHWC convolutions: ~25 % faster steps on CPU
    # one emotion vector per training frame: index = (video, frame) flattened
    offsets = np.cumsum([0] + [len(v["targets"]) for v in train])
    emotions = torch.nn.Parameter(config.emotion_sigma * torch.randn(int(offsets[-1]), config.emotion_dim))
    opt = adam(list(net.parameters()) + [emotions], config.lr)
    loss_fn = objective.KarrasLoss(use_motion=config.motion, use_emotion=config.emotions)
    per_epoch = max(1, len(pairs) // config.batch)          # an epoch: as many samples as training frames
    total_epochs = budget.steps / per_epoch
    plan = StepPlan("Karras", budget, per_epoch, f"{int(offsets[-1]):,} frames", log_plan or log, calibrate=3)
    stopper = EarlyStopping(budget)
    history, sums, n_sums, step = [], {}, 0, 0
    from tqdm import tqdm
    bar = tqdm(total=budget.steps, desc="karras", unit="step", leave=False, disable=not progress)
    while step < budget.steps:
        order = rng.permutation(len(pairs))
        for b in range(per_epoch):
            lr, beta1 = objective.schedule(step / per_epoch, total_epochs, config.lr)
            for g in opt.param_groups:
                g["lr"], g["betas"] = lr, (beta1, g["betas"][1])
            half = config.batch // 2
            rows, x, y = minibatch(train, pairs[order[b * half:(b + 1) * half]], config, rng)
            idx = torch.as_tensor(offsets[rows[:, 0]] + rows[:, 1])
            e = emotions[idx] if config.emotions else torch.zeros(len(rows), config.emotion_dim)
            out = net(x, e.to(config.device), noise=True)
            loss, parts = loss_fn(torch.as_tensor(y, dtype=torch.float32, device=config.device), out, e)
            opt.zero_grad()
            loss.backward()
            opt.step()
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v
            n_sums, step = n_sums + 1, step + 1
            plan.step_done()
            bar.update(1)
            if not budget.is_validation_step(step):
                continue
            row = dict(step=step, epoch=step / per_epoch, **{k: v / n_sums for k, v in sums.items()})
            sums, n_sums = {}, 0
            if on_validation is not None:
                net.eval()
                with torch.no_grad():
                    row.update(on_validation(step, net, emotions.detach()) or {})
                net.train()
            history.append(row)
            bar.set_postfix(position=f"{row['position']:.3f}")
            if "val_position" in row and stopper.update(step, row["val_position"], (net.state_dict(), emotions.detach())):
                log.info("Karras: early stop at step %d of %d (no gain for %d validations); keeping step %d",
                         step, budget.steps, budget.patience, stopper.best_step)
                step = budget.steps
            if step >= budget.steps:
                break
    bar.close()
    if budget.patience is not None and stopper.best_state is not None and stopper.best_step != history[-1]["step"]:
        state, best_emotions = stopper.best_state
        net.load_state_dict(state)
        emotions = best_emotions
        history[-1]["kept_step"] = stopper.best_step
    return net, emotions.detach().cpu().numpy(), history
