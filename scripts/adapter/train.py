#!/usr/bin/env python3
"""Train the tool-choice adapter: a LoRA over the default model's own quantized weights,
taught to raise the name of the tool a request asks for, on the samples data.py and
pack.py make from the tools' examples (nothing else is read).

The adapter acts only where the runtime's gate chooses a tool (`turn::Gate`): on the last
token before the name (re-read with the adapter) and on the name's own tokens, each
attending to the base model's cache of the prompt. Everything else (the prompt's cache,
the arguments, the answer) is the base model's: an adapter applied everywhere raised the
tool choice but changed the arguments the model writes (stop 64: a log level, a count,
linear for angular). Training matches: the context is read without the adapter, with no
gradient; only those few positions carry it.

The model is rebuilt here from the GGUF file the runtime loads (dequantized, the same
weights the runtime multiplies), in llama.cpp's layout: rotary embedding on adjacent
pairs, q and k as the file stores them; so the adapter's tensors are written in the
file's own names and shapes, with no conversion.

Before and after training, on the held-out samples: how often the listed tool with the
highest log-probability of its name is the answering one (the model alone, without the
agent's retrieval prior). Prints both; writes the adapter as a GGUF LoRA (f16).

    train.py MODEL.gguf DATA.npz OUT.gguf [--rank 16] [--epochs 3] [--seconds 240]
"""

import argparse
import math
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

import gguf

DTYPE = {"cuda": torch.bfloat16, "cpu": torch.float32}
TARGETS = ("attn_q", "attn_k", "attn_v", "attn_output", "ffn_gate", "ffn_up", "ffn_down")


def field(reader, key):
    f = reader.fields[key]
    return f.parts[f.data[0]][0]


class Model:
    def __init__(self, path, device, rank, alpha):
        r = gguf.GGUFReader(path)
        self.L = int(field(r, "llama.block_count"))
        self.d = int(field(r, "llama.embedding_length"))
        self.nh = int(field(r, "llama.attention.head_count"))
        self.nkv = int(field(r, "llama.attention.head_count_kv"))
        self.hd = self.d // self.nh
        self.base = float(field(r, "llama.rope.freq_base"))
        self.eps = float(field(r, "llama.attention.layer_norm_rms_epsilon"))
        self.dev = device
        self.w = {}
        for t in r.tensors:
            a = gguf.quants.dequantize(t.data, t.tensor_type)
            shape = [int(x) for x in reversed(t.shape)]
            self.w[t.name] = torch.from_numpy(
                np.array(a.reshape(shape), dtype=np.float32, copy=True)
            ).to(device, DTYPE[device])
        self.out = self.w.get("output.weight", self.w["token_embd.weight"])
        self.scale = alpha / rank
        self.rank, self.alpha = rank, alpha
        g = torch.Generator().manual_seed(46)
        self.lora = {}
        for l in range(self.L):
            for name in TARGETS:
                out_f, in_f = self.w[f"blk.{l}.{name}.weight"].shape
                a = torch.randn(rank, in_f, generator=g) / math.sqrt(in_f)
                b = torch.zeros(out_f, rank)
                self.lora[(l, name)] = (
                    a.to(device).requires_grad_(),
                    b.to(device).requires_grad_(),
                )

    def params(self):
        return [p for ab in self.lora.values() for p in ab]

    def lin(self, x, l, name, use_lora):
        y = x @ self.w[f"blk.{l}.{name}.weight"].T
        if use_lora:
            a, b = self.lora[(l, name)]
            y = y + ((x @ a.to(x.dtype).T) @ b.to(x.dtype).T) * self.scale
        return y

    def rms(self, x, w):
        x32 = x.float()
        x32 = x32 * torch.rsqrt(x32.pow(2).mean(-1, keepdim=True) + self.eps)
        return x32.to(x.dtype) * w

    def rope(self, x, pos0):
        # x: B, H, T, D; llama.cpp's "normal" rotary embedding: adjacent pairs.
        T, D = x.shape[2], x.shape[3]
        inv = self.base ** (-torch.arange(0, D, 2, device=x.device, dtype=torch.float32) / D)
        pos = torch.arange(pos0, pos0 + T, device=x.device, dtype=torch.float32)
        ang = pos[:, None] * inv[None, :]
        cos, sin = ang.cos().to(x.dtype), ang.sin().to(x.dtype)
        x1, x2 = x[..., 0::2], x[..., 1::2]
        return torch.stack([x1 * cos - x2 * sin, x1 * sin + x2 * cos], -1).flatten(-2)

    def forward(self, tokens, use_lora=True, pos0=0, prefix=None, keep=False):
        """Hidden states after the final norm; with `keep`, each layer's (k, v);
        with `prefix` (per layer, the kept (k, v) parts of one sequence), `tokens`
        continue it (each row)."""
        B, T = tokens.shape
        x = self.w["token_embd.weight"][tokens]
        kept = []
        g = self.nh // self.nkv
        for l in range(self.L):
            h = self.rms(x, self.w[f"blk.{l}.attn_norm.weight"])
            q = self.lin(h, l, "attn_q", use_lora).view(B, T, self.nh, self.hd).transpose(1, 2)
            k = self.lin(h, l, "attn_k", use_lora).view(B, T, self.nkv, self.hd).transpose(1, 2)
            v = self.lin(h, l, "attn_v", use_lora).view(B, T, self.nkv, self.hd).transpose(1, 2)
            q, k = self.rope(q, pos0), self.rope(k, pos0)
            if keep:
                kept.append((k, v))
            if prefix is not None:
                a = self.attend_after(q, k, v, prefix[l])
            else:
                k, v = k.repeat_interleave(g, 1), v.repeat_interleave(g, 1)
                a = F.scaled_dot_product_attention(q, k, v, is_causal=True)
            x = x + self.lin(a.transpose(1, 2).reshape(B, T, self.d), l, "attn_output", use_lora)
            h = self.rms(x, self.w[f"blk.{l}.ffn_norm.weight"])
            f = F.silu(self.lin(h, l, "ffn_gate", use_lora)) * self.lin(h, l, "ffn_up", use_lora)
            x = x + self.lin(f, l, "ffn_down", use_lora)
        return self.rms(x, self.w["output_norm.weight"]), kept

    def attend_after(self, q, k, v, parts):
        """Attention of each row's tokens to the cached parts (one sequence's, shared by
        every row, never copied per row) and, causally, to the row's own tokens. Heads
        grouped over their k, v head, as llama.cpp groups them."""
        B, _, T, D = q.shape
        qg = q.view(B, self.nkv, self.nh // self.nkv, T, D) / math.sqrt(D)
        scores = [qg @ pk[:, :, None].transpose(-1, -2) for pk, _ in parts]
        own = qg @ k[:, :, None].transpose(-1, -2)
        causal = torch.ones(T, T, dtype=torch.bool, device=q.device).tril()
        scores.append(own.masked_fill(~causal, float("-inf")))
        w = torch.softmax(torch.cat(scores, -1).float(), -1).to(q.dtype)
        out, at = 0, 0
        for pk, pv in parts:
            n = pk.shape[2]
            out = out + w[..., at: at + n] @ pv[:, :, None]
            at += n
        out = out + w[..., at:] @ v[:, :, None]
        return out.reshape(B, self.nh, T, D)

    def logits(self, h):
        return (h @ self.out.T).float()

    def load(self, path):
        r = gguf.GGUFReader(path)
        t = {x.name: x for x in r.tensors}
        for (l, name), (a, b) in self.lora.items():
            for p, suffix in ((a, "lora_a"), (b, "lora_b")):
                x = t[f"blk.{l}.{name}.weight.{suffix}"]
                v = np.array(x.data, dtype=np.float32).reshape(p.shape)
                with torch.no_grad():
                    p.copy_(torch.from_numpy(v))

    def save(self, path, arch="llama"):
        w = gguf.GGUFWriter(path, arch)
        w.add_type("adapter")
        w.add_string("adapter.type", "lora")
        w.add_float32("adapter.lora.alpha", float(self.alpha))
        w.add_string("general.name", "ferrosa tool choice")
        for (l, name), (a, b) in self.lora.items():
            w.add_tensor(f"blk.{l}.{name}.weight.lora_a", a.detach().half().cpu().numpy())
            w.add_tensor(f"blk.{l}.{name}.weight.lora_b", b.detach().half().cpu().numpy())
        w.write_header_to_file()
        w.write_kv_data_to_file()
        w.write_tensors_to_file()
        w.close()


class Data:
    def __init__(self, path, device):
        z = np.load(path)
        self.ctx, self.off = z["ctx"].astype(np.int64), z["ctx_off"]
        self.names = list(z["names"])
        self.name_tok = z["name_tok"].astype(np.int64)
        self.name_off = z["name_off"]
        self.cand, self.target, self.held = z["cand"], z["target"], z["held"]
        self.robot, self.robots = z["robot"], list(z["robots"])
        self.stable = z["stable"] if "stable" in z else np.zeros(len(self.target), np.int64)
        self.dev = device
        self.truncate = 0
        self.cache = False
        self.prefixes = None

    def context(self, i):
        c = self.ctx[self.off[i]: self.off[i + 1]]
        return c[-self.truncate:] if self.truncate else c

    def name(self, j):
        return self.name_tok[self.name_off[j]: self.name_off[j + 1]]


class Prefixes:
    """The base model's cache of each sample's context but its last token. A system
    message several samples share is read once (`stable` tokens of the context); each
    sample's own part after it is read once and kept. With neither, the whole context
    is read each time (on a GPU that is cheap; on a CPU only shared prefixes are used)."""

    def __init__(self, model, data):
        self.model, self.data = model, data
        self.shared, self.own = {}, {}
        counts = {}
        for i in range(len(data.target)):
            counts[self.key(i)] = counts.get(self.key(i), 0) + 1
        self.counts = counts

    def key(self, i):
        c = self.data.context(i)
        return hash(c[: self.data.stable[i]].tobytes())

    def is_shared(self, i):
        return self.counts[self.key(i)] > 1

    @torch.no_grad()
    def of(self, i):
        m, ctx = self.model, self.data.context(i)
        if not self.data.cache or not self.is_shared(i):
            _, kept = m.forward(torch.tensor(ctx[:-1], device=m.dev)[None], False, keep=True)
            return [[kv] for kv in kept]
        st, key = int(self.data.stable[i]), self.key(i)
        if key not in self.shared:
            _, self.shared[key] = m.forward(torch.tensor(ctx[:st], device=m.dev)[None], False, keep=True)
        base = self.shared[key]
        if i not in self.own:
            own = torch.tensor(ctx[st:-1], device=m.dev)[None]
            _, self.own[i] = m.forward(own, False, pos0=st, prefix=[[kv] for kv in base], keep=True)
        return [[b, o] for b, o in zip(base, self.own[i])]


def suffix_logprobs(model, data, i, rows, use_lora):
    """Sample i's context read without the adapter up to its last token; then, for each
    token list in `rows`, that last token and the list's tokens read with it. Returns
    log-probabilities (rows, len, vocab): position p predicts the list's token p."""
    ctx = data.context(i)
    kept = data.prefixes.of(i)
    width = max(len(t) for t in rows)
    batch = torch.zeros(len(rows), width, dtype=torch.long, device=model.dev)
    batch[:, 0] = int(ctx[-1])
    for r, t in enumerate(rows):
        batch[r, 1: len(t)] = torch.tensor(t[:-1])
    h, _ = model.forward(batch, use_lora, pos0=len(ctx) - 1, prefix=kept)
    return torch.log_softmax(model.logits(h), -1)


def choose(model, data, i, use_lora):
    """The listed tool whose name has the highest log-probability after sample i."""
    listed = [j for j in range(len(data.names)) if data.cand[i, j]]
    toks = [data.name(j) for j in listed]
    lp = suffix_logprobs(model, data, i, toks, use_lora)
    scores = [sum(lp[r, p, t[p]].item() for p in range(len(t))) for r, t in enumerate(toks)]
    return listed[int(np.argmax(scores))]


@torch.no_grad()
def accuracy(model, data, use_lora):
    idx = np.nonzero(data.held)[0]
    right = [choose(model, data, i, use_lora) == data.target[i] for i in idx]
    by = {}
    for i, ok in zip(idx, right):
        by.setdefault(data.robots[data.robot[i]], []).append(ok)
    parts = ", ".join(f"{k} {sum(v)}/{len(v)}" for k, v in sorted(by.items()))
    return sum(right), len(right), parts


def loss_of(model, data, i):
    """The answering name's negative log-likelihood after sample i (summed over its tokens)."""
    t = data.name(data.target[i])
    lp = suffix_logprobs(model, data, i, [t], True)
    return -sum(lp[0, p, t[p]] for p in range(len(t)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("data")
    ap.add_argument("out")
    ap.add_argument("--rank", type=int, default=16)
    ap.add_argument("--alpha", type=float, default=32.0)
    ap.add_argument("--epochs", type=float, default=3.0)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--lr", type=float, default=5e-4)
    ap.add_argument("--seconds", type=float, default=240.0)
    ap.add_argument("--limit", type=int, default=0, help="first N samples only (a smoke run)")
    ap.add_argument("--skip-before", action="store_true")
    ap.add_argument("--truncate", type=int, default=0, help="last N context tokens (a smoke run)")
    ap.add_argument("--shared-only", action="store_true",
                    help="only samples whose system message others share, each prefix read once (a CPU run)")
    ap.add_argument("--init", help="start from this adapter (GGUF LoRA of the same rank)")
    ap.add_argument("--balance", action="store_true",
                    help="weigh each tool alike, however many examples it has")
    args = ap.parse_args()
    device = "cuda" if torch.cuda.is_available() else "cpu"
    t0 = time.time()
    model = Model(args.model, device, args.rank, args.alpha)
    data = Data(args.data, device)
    data.truncate = args.truncate
    data.cache = args.shared_only
    data.prefixes = Prefixes(model, data)
    if args.shared_only:
        alone = np.array([not data.prefixes.is_shared(i) for i in range(len(data.target))])
        data.held[alone] = False
        data.skip = alone
    else:
        data.skip = np.zeros(len(data.target), bool)
    if args.init:
        model.load(args.init)
        print(f"started from {args.init}", flush=True)
    if args.limit:
        held = np.nonzero(data.held)[0]
        data.held[held[args.limit:]] = False
    print(f"loaded in {time.time() - t0:.1f} s on {device}", flush=True)
    if not args.skip_before:
        r, n, parts = accuracy(model, data, False)
        print(f"held out, before: {r}/{n} ({parts})", flush=True)
    train = np.nonzero(~data.held & ~data.skip)[0]
    if args.limit:
        train = train[: args.limit]
    # Each tool weighs the same in all, however many examples it has: the agent's own
    # prior (retrieval) already says which tools a request is near; the adapter is to
    # read requests, not to learn which tools have the most examples.
    counts = np.bincount(data.target[train], minlength=len(data.names)).astype(np.float64)
    weight = np.where(counts > 0, counts[counts > 0].mean() / np.maximum(counts, 1), 0.0)
    if not args.balance:
        weight[:] = 1.0
    steps = max(1, int(len(train) * args.epochs / args.batch))
    opt = torch.optim.AdamW(model.params(), lr=args.lr, weight_decay=0.0)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: min(1.0, (s + 1) / 20) * 0.5 * (1 + math.cos(math.pi * min(s, steps) / steps))
    )
    rng = np.random.default_rng(46)
    order = np.concatenate([rng.permutation(train) for _ in range(math.ceil(args.epochs) + 1)])
    t1 = time.time()
    for step in range(steps):
        rows = order[step * args.batch: (step + 1) * args.batch]
        opt.zero_grad()
        total = 0.0
        for i in rows:
            loss = loss_of(model, data, i) * weight[data.target[i]] / len(rows)
            loss.backward()
            total += loss.item()
        torch.nn.utils.clip_grad_norm_(model.params(), 1.0)
        opt.step()
        sched.step()
        if step % 20 == 0 or step == steps - 1:
            print(f"step {step + 1}/{steps} loss {total:.3f} {time.time() - t1:.0f} s", flush=True)
        if step + 1 == steps // 2:
            model.save(args.out.replace(".gguf", "-half.gguf"))
            print(f"saved the adapter at step {step + 1}", flush=True)
        if time.time() - t1 > args.seconds:
            print(f"stopped at step {step + 1} of {steps}: time", flush=True)
            break
    model.save(args.out)
    r, n, parts = accuracy(model, data, True)
    print(f"held out, after: {r}/{n} ({parts})", flush=True)
    print(f"total {time.time() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    torch.manual_seed(46)
    sys.exit(main())
