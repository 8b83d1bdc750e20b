#!/usr/bin/env python3
"""Count the word literals left in the code that reads requests: string literals of one
to three lowercase words in src/reading/, src/agent/, src/lexicon.rs and
src/stop_intent.rs, tests and comments left out (JSON keys and log words count too, so
the figure is an upper bound). The words that steer the agent belong in data/words/.

usage: scripts/word-literals.py   (from the repository root)
"""
import glob
import re

FILES = sorted(glob.glob("src/reading/*.rs") + glob.glob("src/agent/*.rs")) + [
    "src/lexicon.rs",
    "src/stop_intent.rs",
]
WORD = re.compile(r"[a-zà-ÿß]+( [a-zà-ÿß]+){0,2}")

total = 0
for path in FILES:
    text = open(path, encoding="utf-8").read()
    text = text.split("#[cfg(test)]", 1)[0]
    text = re.sub(r"//[^\n]*", "", text)
    found = [s for s in re.findall(r'"([^"\\\n]{1,40})"', text) if WORD.fullmatch(s)]
    if found:
        print(f"{len(found):5} {path}")
        total += len(found)
print(f"{total:5} in all")
