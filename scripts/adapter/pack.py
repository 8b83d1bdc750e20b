#!/usr/bin/env python3
"""Pack the tokenized samples (adapter_tokens's output) into one compressed array file
for the training run: each sample's context (prompt and the call's opening; how much of it
the system message decides, which samples of one robot share), the tool
names as token ids, which names each sample's system message lists, the answering name,
and whether the sample is held out.

    pack.py TOKENS.jsonl OUT.npz
"""

import json
import sys

import numpy as np


def main():
    src, out = sys.argv[1], sys.argv[2]
    ctx, ctx_off, cand_rows, target, held, robot, stable = [], [0], [], [], [], [], []
    names, name_toks = [], []
    robots = []
    for line in open(src, encoding="utf-8"):
        s = json.loads(line)
        for n, toks in s["names"].items():
            if n not in names:
                names.append(n)
                name_toks.append(toks)
        c = s["prompt"] + s["opening"]
        ctx += c
        ctx_off.append(len(ctx))
        cand_rows.append([n in s["names"] for n in names])
        target.append(names.index(s["tool"]))
        held.append(bool(s["held_out"]))
        stable.append(s["stable"])
        if s["robot"] not in robots:
            robots.append(s["robot"])
        robot.append(robots.index(s["robot"]))
    cand = np.zeros((len(cand_rows), len(names)), dtype=bool)
    for i, row in enumerate(cand_rows):
        cand[i, : len(row)] = row
    name_off = np.cumsum([0] + [len(t) for t in name_toks])
    np.savez_compressed(
        out,
        ctx=np.array(ctx, dtype=np.uint16),
        ctx_off=np.array(ctx_off, dtype=np.int64),
        names=np.array(names),
        name_tok=np.array([t for ts in name_toks for t in ts], dtype=np.uint16),
        name_off=name_off.astype(np.int64),
        cand=cand,
        target=np.array(target, dtype=np.int64),
        held=np.array(held),
        stable=np.array(stable, dtype=np.int64),
        robot=np.array(robot, dtype=np.int64),
        robots=np.array(robots),
    )
    print(f"{len(target)} samples, {len(names)} names, {len(ctx)} context tokens", file=sys.stderr)


if __name__ == "__main__":
    main()
