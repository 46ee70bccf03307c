#!/usr/bin/env python3
"""Writes a random-weight bundle with the paper's network shape, for benchmarks only.

    python3 benches/make_bench_bundle.py -o /tmp/paper.vamos [--width 1.0] [--m 10]

U-Net: 4 levels, filters [32, 64, 128, 192] * width, 3 conv3x3+ReLU per level, 2x2
average pooling, bilinear x2 upsampling (align_corners) + skip concat, C = filters[0]
output channels; prior: the same encoder half, global mean, 1x1 conv to mu and log sigma
(L = 6); fcomb: tile z, concat, three 1x1 conv+ReLU, final 1x1 to 2 channels
(REFERENCE.md section 3). The weights are random: use it for timing, not for scores.
The training package (clients/python) writes the real bundles.
"""

import argparse
import hashlib
import io
import json
import zipfile

import torch
from torch import nn
import torch.nn.functional as F


def block(cin, cout, n):
    layers = []
    for i in range(n):
        layers += [nn.Conv2d(cin if i == 0 else cout, cout, 3, padding=1), nn.ReLU()]
    return nn.Sequential(*layers)


class Down(nn.Module):
    def __init__(self, cin, filters, convs):
        super().__init__()
        self.blocks = nn.ModuleList()
        for i, f in enumerate(filters):
            self.blocks.append(block(cin if i == 0 else filters[i - 1], f, convs))

    def forward(self, x):
        skips = []
        for i, b in enumerate(self.blocks):
            if i > 0:
                x = F.avg_pool2d(x, 2)
            x = b(x)
            skips.append(x)
        return skips


class Encoder(nn.Module):
    def __init__(self, filters, convs, latent):
        super().__init__()
        self.down = Down(2, filters, convs)
        self.up = nn.ModuleList()
        for i in range(len(filters) - 1, 0, -1):
            self.up.append(block(filters[i] + filters[i - 1], filters[i - 1], convs))
        self.prior = Down(2, filters, convs)
        self.mu_sigma = nn.Conv2d(filters[-1], 2 * latent, 1)
        self.latent = latent

    def forward(self, flow):
        skips = self.down(flow)
        x = skips[-1]
        for j, b in enumerate(self.up):
            skip = skips[-2 - j]
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=True)
            x = b(torch.cat([x, skip], dim=1))
        p = self.prior(flow)[-1].mean(dim=(2, 3), keepdim=True)
        ms = self.mu_sigma(p).flatten(1)
        return x, ms[:, : self.latent], ms[:, self.latent:]


class Head(nn.Module):
    def __init__(self, channels, latent, hidden, layers):
        super().__init__()
        convs = [nn.Conv2d(channels + latent, hidden, 1)]
        convs += [nn.Conv2d(hidden, hidden, 1) for _ in range(layers - 1)]
        self.convs = nn.ModuleList(convs)
        self.out = nn.Conv2d(hidden, 2, 1)

    def forward(self, features, z):
        zt = z[:, :, None, None].expand(-1, -1, features.shape[2], features.shape[3])
        x = torch.cat([features, zt], dim=1)
        for c in self.convs:
            x = F.relu(c(x))
        return self.out(x)


def export(module, args, names_in, names_out, dyn):
    buf = io.BytesIO()
    torch.onnx.export(module, args, buf, input_names=names_in, output_names=names_out,
                      dynamic_axes=dyn, opset_version=17, dynamo=False)
    return buf.getvalue()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--width", type=float, default=1.0)
    ap.add_argument("--m", type=int, default=10)
    args = ap.parse_args()
    torch.manual_seed(0)
    filters = [max(1, round(f * args.width)) for f in (32, 64, 128, 192)]
    latent, convs = 6, 3
    c = filters[0]
    enc, head = Encoder(filters, convs, latent).eval(), Head(c, latent, c, 3).eval()
    x = torch.zeros(1, 2, 64, 64)
    n = {0: "N"}
    enc_b = export(enc, (x,), ["flow"], ["features", "prior_mu", "prior_log_sigma"],
                   {"flow": n, "features": n, "prior_mu": n, "prior_log_sigma": n})
    head_b = export(head, (torch.zeros(1, c, 64, 64), torch.zeros(1, latent)), ["features", "z"],
                    ["flow"], {"features": n, "z": n, "flow": n})
    params = sum(p.numel() for p in enc.parameters()) + sum(p.numel() for p in head.parameters())
    man = {
        "format": "vamos-model", "format_version": 1,
        "name": f"bench-random-w{args.width:g}", "created": "2026-11-22T00:00:00Z", "opset": 17,
        "architecture": {"filters": filters, "convs_per_level": convs, "latent_dim": latent,
                         "feature_channels": c, "fcomb_channels": c, "fcomb_layers": 3,
                         "parameters_total": params, "parameters_inference": params},
        "input": {"size": 64, "channels": 2, "clip_px": 15.0, "reference_width_px": 640},
        "temporal": {"a": 5, "b": 4, "m": args.m},
        "flow_variant": "masked",
        "processing": {"width": 640, "height": 480, "stride": 3},
        "training": {"dataset": "random weights, benchmarks only"},
        "members": {k: {"sha256": hashlib.sha256(v).hexdigest()}
                    for k, v in (("encoder.onnx", enc_b), ("head.onnx", head_b))},
    }
    with zipfile.ZipFile(args.out, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("manifest.json", json.dumps(man, indent=1))
        z.writestr("encoder.onnx", enc_b)
        z.writestr("head.onnx", head_b)
    print(f"wrote {args.out}: filters {filters}, {params} parameters")


if __name__ == "__main__":
    main()
