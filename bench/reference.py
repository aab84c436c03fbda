"""PyTorch eager reference for `oneshot-lab bench train --config paper`.

The same network as the tool's transformer policy (ResNet-18 trunk, sinusoidal positions, two causal non-local
attention layers, a non-causal task attention layer and unpadded temporal convolution, spatial softmax, one shared
embedding MLP, the logistic-mixture action and inverse heads and the 2-D point head), the same losses and
weights, the same batch of random frames, timed the same way: `--warmup` untimed steps (3, as the tool's), then `--steps` steps between
device synchronisations. Used only to compare step times on one GPU; nothing in the tool runs Python.

    python3 bench/reference.py --device cuda --precision bf16 --memory-format channels_last
"""

import argparse
import math
import time

import torch
import torch.nn as nn
import torch.nn.functional as F
import torchvision

ACTION_DIM = 8


def positional_encoding(tokens, channels, device):
    pos = torch.arange(tokens, device=device, dtype=torch.float32).unsqueeze(1)
    i = torch.arange(0, channels, 2, device=device, dtype=torch.float32)
    angle = pos * torch.exp(i * (-math.log(10_000.0) / channels)).unsqueeze(0)
    return torch.stack([angle.sin(), angle.cos()], 2).view(tokens, channels)


def frame_causal_mask(frames, per_frame, visible, device):
    frame = torch.arange(frames, device=device).repeat_interleave(per_frame)
    q, k = frame.unsqueeze(1), frame.unsqueeze(0)
    return (k <= q) | (k < visible)


class Attention(nn.Module):
    def __init__(self, channels, inner, heads, dropout):
        super().__init__()
        self.heads, self.inner, self.dropout = heads, inner, dropout
        self.temperature = math.sqrt(channels)
        self.query = nn.Linear(channels, inner, bias=False)
        self.key = nn.Linear(channels, inner, bias=False)
        self.value = nn.Linear(channels, inner, bias=False)
        self.out = nn.Linear(inner, channels)
        self.norm = nn.BatchNorm1d(channels)

    def forward(self, x, mask):
        b, n, _ = x.shape

        def split(t):
            return t.view(b, n, self.heads, -1).transpose(1, 2)

        q, k, v = split(self.query(x)), split(self.key(x)), split(self.value(x))
        scores = q @ k.transpose(-2, -1) / self.temperature
        if mask is not None:
            scores = scores.masked_fill(~mask, float("-inf"))
        attended = (scores.softmax(-1, dtype=torch.float32).to(v.dtype) @ v).transpose(1, 2).reshape(b, n, -1)
        y = F.relu(self.out(attended))
        if self.training and self.dropout > 0:
            keep = (torch.rand(b, 1, y.shape[-1], device=y.device) >= self.dropout).to(y.dtype)
            y = y * keep / (1 - self.dropout)
        return self.norm((x + y).transpose(1, 2)).transpose(1, 2)


def spatial_softmax(x):
    n, c, h, w = x.shape
    p = x.reshape(n, c, h * w).softmax(-1, dtype=torch.float32).view(n, c, h, w)
    xs = torch.linspace(-1, 1, w, device=x.device)
    ys = torch.linspace(-1, 1, h, device=x.device)
    return torch.cat([(p.sum(2) * xs).sum(-1), (p.sum(3) * ys).sum(-1)], 1)


class Embed(nn.Module):
    def __init__(self, inp, hidden, latent, dropout):
        super().__init__()
        self.hidden, self.out, self.dropout = nn.Linear(inp, hidden), nn.Linear(hidden, latent), dropout

    def forward(self, x):
        y = self.out(F.relu(F.dropout(self.hidden(x), self.dropout, self.training)))
        return y / y.float().square().sum(-1, keepdim=True).sqrt().clamp_min(1e-8)


class MixtureHead(nn.Module):
    def __init__(self, hidden, mixtures):
        super().__init__()
        self.mixtures = mixtures
        self.params = nn.Linear(hidden, 2 * ACTION_DIM * mixtures)
        self.log_scale = nn.Parameter(torch.zeros(ACTION_DIM, 1))

    def forward(self, h):
        out = self.params(h).view(*h.shape[:-1], ACTION_DIM, 2 * self.mixtures)
        means, logits = out.split(self.mixtures, -1)
        return means, self.log_scale.clamp_min(-7.0).expand_as(means), logits


def mixture_nll(means, log_scales, logits, x, bins=256, log_scale_min=-7.0):
    means, log_scales, logits = means.float(), log_scales.float(), logits.float()
    half_bin = 1.0 / (bins - 1)
    x = x.unsqueeze(-1)
    log_scales = log_scales.clamp_min(log_scale_min)
    centered = x - means
    inv_s = torch.exp(-log_scales)
    plus_in, min_in = inv_s * (centered + half_bin), inv_s * (centered - half_bin)
    cdf_delta = plus_in.sigmoid() - min_in.sigmoid()
    log_cdf_plus = plus_in - F.softplus(plus_in)
    log_one_minus_cdf_min = -F.softplus(min_in)
    mid_in = inv_s * centered
    log_pdf_mid = mid_in - log_scales - 2.0 * F.softplus(mid_in)
    interior = torch.where(
        cdf_delta > 1e-5, cdf_delta.clamp_min(1e-12).log(), log_pdf_mid - math.log((bins - 1) / 2.0)
    )
    upper = torch.where(x > 0.999, log_one_minus_cdf_min, interior)
    log_probs = torch.where(x < -0.999, log_cdf_plus, upper)
    return -torch.logsumexp(log_probs + logits.log_softmax(-1), -1).mean()


def point_nll(y, target):
    y = y.float()
    mean, a, c, b = y[:, :2], F.softplus(y[:, 2]) + 0.03, y[:, 3], F.softplus(y[:, 4]) + 0.03
    d = target - mean
    z1 = d[:, 0] / a
    z2 = (d[:, 1] - c * z1) / b
    return ((z1.square() + z2.square()) * 0.5 + a.log() + b.log() + math.log(2 * math.pi)).mean()


class Transformer(nn.Module):
    def __init__(self, layers=2, inner=128, heads=4, dropout=0.2, hidden=256, latent=40, policy=32, point=40,
                 mixtures=2):
        super().__init__()
        r = torchvision.models.resnet18()
        self.trunk = nn.Sequential(r.conv1, r.bn1, r.relu, r.maxpool, r.layer1, r.layer2, r.layer3, r.layer4)
        c = 512
        self.dropout = dropout
        self.channels_last = False
        self.causal = nn.ModuleList(Attention(c, inner, heads, dropout) for _ in range(layers))
        self.task_attention = Attention(c, inner, heads, dropout)
        self.task_conv = nn.Conv3d(c, c, (3, 1, 1))
        self.embed = Embed(2 * c, hidden, latent, dropout)
        self.policy = nn.Linear(2 * latent, policy)
        self.inverse = nn.Linear(2 * latent, policy)
        self.action_head = MixtureHead(policy, mixtures)
        self.point_hidden, self.point_out = nn.Linear(latent, point), nn.Linear(point, 5)

    def forward(self, context, agent):
        tc, ta = context.shape[1], agent.shape[1]
        images = torch.cat([context, agent], 1)
        b, t = images.shape[:2]
        images = images.flatten(0, 1)
        if self.channels_last:
            # As the tool does: NCHW sizes, NHWC strides, kept through the trunk.
            images = images.contiguous(memory_format=torch.channels_last)
        f = self.trunk(images)
        c, h, w = f.shape[1:]
        hw = h * w
        x = f.view(b, t, c, h, w).permute(0, 1, 3, 4, 2).reshape(b, t * hw, c)
        x = F.dropout(x + positional_encoding(t * hw, c, x.device), self.dropout, self.training)
        mask = frame_causal_mask(t, hw, tc, x.device)
        for layer in self.causal:
            x = layer(x, mask)
        frames = x.view(b, t, h, w, c).permute(0, 1, 4, 2, 3)
        e = self.embed(spatial_softmax(frames[:, tc:].reshape(b * ta, c, h, w))).view(b, ta, -1)
        task_tokens = self.task_attention(x[:, : (tc + 1) * hw], None)
        task_frames = task_tokens.view(b, tc + 1, h, w, c).permute(0, 4, 1, 2, 3)
        task = self.embed(spatial_softmax(self.task_conv(task_frames).mean(2)))
        joint = torch.cat([task.unsqueeze(1).expand(b, ta, -1), e], -1)
        actions = self.action_head(F.relu(self.policy(joint)))
        pairs = torch.cat([e[:, :-1], e[:, 1:]], -1)
        inverse = self.action_head(F.relu(self.inverse(pairs)))
        point = self.point_out(F.relu(self.point_hidden(task)))
        return actions, inverse, point


def losses(model, batch):
    actions, inverse, point = model(batch["context"], batch["agent"])
    steps = batch["actions"].shape[1]
    bc = mixture_nll(*(p[:, :steps] for p in actions), batch["actions"])
    inv = mixture_nll(*inverse, batch["actions"])
    return bc + inv + 0.1 * point_nll(point, batch["points"])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--precision", choices=["fp32", "bf16"], default="fp32")
    ap.add_argument("--memory-format", choices=["contiguous", "channels_last"], default="contiguous")
    ap.add_argument("--cudnn-benchmark", action="store_true", help="let cuDNN pick convolution algorithms by timing")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3, help="untimed steps first, as `bench train --warmup`")
    ap.add_argument("--batch", type=int, default=30)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--width", type=int, default=320)
    a = ap.parse_args()
    device = torch.device(a.device)
    torch.backends.cudnn.benchmark = a.cudnn_benchmark
    torch.manual_seed(0)
    model = Transformer().to(device)
    if a.memory_format == "channels_last":
        model.trunk.to(memory_format=torch.channels_last)
        model.channels_last = True
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    b, tc, ta = a.batch, 4, 7
    batch = {
        "context": torch.randn(b, tc, 3, a.height, a.width, device=device),
        "agent": torch.randn(b, ta, 3, a.height, a.width, device=device),
        "actions": torch.rand(b, ta - 1, ACTION_DIM, device=device) * 2 - 1,
        "points": torch.rand(b, 2, device=device) * 2 - 1,
    }

    def step():
        opt.zero_grad(set_to_none=True)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=a.precision == "bf16"):
            loss = losses(model, batch)
        loss.backward()
        opt.step()
        return loss

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    for _ in range(a.warmup):
        step()
    sync()
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    start = time.perf_counter()
    for _ in range(a.steps):
        loss = step()
    sync()
    s = (time.perf_counter() - start) / a.steps
    parameters = sum(p.numel() for p in model.parameters() if p.requires_grad)
    memory = f"{torch.cuda.max_memory_allocated(device) / 2**30:.2f} GiB" if device.type == "cuda" else "n/a"
    print(
        f"pytorch eager reference: {a.height}x{a.width}, batch {b}, {a.device}, {a.precision}, {a.memory_format}, "
        f"cudnn.benchmark {a.cudnn_benchmark}, torch {torch.__version__}"
    )
    print(
        f"  {parameters} parameters, {s:.4f} s/step, {1 / s:.2f} steps/s, {b / s:.1f} samples/s, "
        f"peak allocated {memory}, loss {loss.item():.3f}, 60k steps {60_000 * s / 3600:.2f} h"
    )


if __name__ == "__main__":
    main()
