#!/usr/bin/env python3
"""Training requests for the tool-choice adapter, made from what describes the tools.

Each sample is the first turn the agent shows the model: a robot's system message (its
prompt and the tools it lists, captured by capture.sh) and a request, with the notes the
agent adds (the answer's language, the tools that fit), and the tool that answers it. The
requests are the tools' own examples (data/examples/<lang>.toml) and those the robot
prompt files add under [examples] (by tool name); no request of any suite is read here.

Each robot's system message is used as captured and once more with its tools shuffled and
some left out (never the answering one), so the adapter learns to read the list it is
shown rather than one list's order. The "Tools that fit" note is drawn the way retrieval
errs: the answering tool among two others most of the time, left out sometimes.

About one request in seven (by a hash of its text, so the split is stable) is held out
for the training run's own check.

    data.py SYSTEM_DIR OUT.jsonl
"""

import hashlib
import json
import random
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LANGS = {"en": "English", "es": "Spanish", "fr": "French", "de": "German",
         "it": "Italian", "pt": "Portuguese"}
ROBOTS = {"sim": "turtlesim.toml", "arm": "arm.toml"}
TOOL_LINE = re.compile(r'^\{"name": "([a-z0-9_]+)"')
# Tools the agent never has the model choose by a request's words alone.
NEVER = {"reply"}
HINTED = 3


def held_out(request: str) -> bool:
    return hashlib.sha256(request.encode()).digest()[0] % 7 == 0


def examples():
    """(tool, request, language code) from the shipped examples and the robots' files."""
    out = []
    for lang in LANGS:
        table = tomllib.loads((ROOT / f"data/examples/{lang}.toml").read_text())
        for tool, reqs in table.items():
            out += [(tool, r, lang, None) for r in reqs]
    for robot, file in ROBOTS.items():
        table = tomllib.loads((ROOT / "prompts" / file).read_text()).get("examples", {})
        for tool, reqs in table.items():
            if tool.startswith("/"):
                continue  # about one of the robot's names, not a tool
            out += [(tool, r, "en", robot) for r in reqs]
    return out


def split_system(text: str):
    """The system message as (head, tool lines, tail)."""
    lines = text.split("\n")
    start, end = lines.index("<tools>") + 1, lines.index("</tools>")
    return lines[:start], lines[start:end], lines[end:]


def variant(system: str, keep: str, rng: random.Random) -> str:
    head, tools, tail = split_system(system)
    tools = [t for t in tools
             if TOOL_LINE.match(t).group(1) == keep or rng.random() > 0.3]
    rng.shuffle(tools)
    return "\n".join(head + tools + tail)


def hint(tool: str, names: list, rng: random.Random) -> str:
    others = [n for n in names if n != tool and n not in NEVER]
    family = tool.rsplit("_", 1)[0]
    near = [n for n in others if n.startswith(family)]
    pool = near + rng.sample(others, min(len(others), 4))
    picked = []
    for n in pool:
        if n not in picked:
            picked.append(n)
    rng.shuffle(picked)
    if rng.random() < 0.85:
        fit = [tool] + picked[: HINTED - 1]
        rng.shuffle(fit)
    else:
        fit = picked[:HINTED]
    return f"(Tools that fit: {', '.join(fit)}.)"


def main():
    sys_dir, out_path = Path(sys.argv[1]), Path(sys.argv[2])
    rng = random.Random(46)
    samples = []
    for robot in ROBOTS:
        system = (sys_dir / f"{robot}.txt").read_text()
        names = [TOOL_LINE.match(l).group(1) for l in split_system(system)[1]]
        for tool, request, lang, only in examples():
            if tool not in names or tool in NEVER or only not in (None, robot):
                continue
            for shown in (system, variant(system, tool, rng)):
                user = request
                if lang != "en":
                    user += f"\n(Answer in {LANGS[lang]}.)"
                user += "\n" + hint(tool, names, rng)
                samples.append({"robot": robot, "system": shown, "user": user,
                                "tool": tool, "held_out": held_out(request)})
    with out_path.open("w") as f:
        for s in samples:
            f.write(json.dumps(s, ensure_ascii=False) + "\n")
    held = sum(s["held_out"] for s in samples)
    print(f"{len(samples)} samples ({held} held out) from "
          f"{len({s['user'].split(chr(10))[0] for s in samples})} requests", file=sys.stderr)


if __name__ == "__main__":
    main()
