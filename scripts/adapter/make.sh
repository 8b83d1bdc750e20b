#!/usr/bin/env bash
# The tool chooser's adapter (data/adapters/smollm2-135m-tools.gguf), from the tools'
# examples to the GGUF LoRA file; README: Understanding requests.
#
#   scripts/adapter/make.sh prepare WORK     # here: samples, tokens, the packed data
#   scripts/adapter/make.sh train WORK [ARGS] # where torch is: train.py on WORK/data.npz
#
# prepare needs a release build (`cargo build --release --example adapter_tokens` and the
# ferrosa binary), the arm peer's virtual environment (target/rosvenv, for capture.sh)
# and the `gguf` Python package (PyPI; or gguf-py of a llama.cpp checkout). train
# needs Python with torch, numpy, pyyaml and gguf; a GPU takes a
# few minutes, a CPU (`--shared-only`: the samples whose system message others share)
# about half an hour a few epochs.
#
# The adapter shipped at stop 64 (data/adapters/smollm2-135m-tools.gguf) was trained in
# two runs: on an H200, `--rank 8 --alpha 16 --epochs 5 --seconds 130`, from scratch over
# every sample (it stopped after 37 steps of 8: the device's time ran out); then on 2 CPU
# cores, `--shared-only --balance --init THAT.gguf --rank 8 --alpha 16 --epochs 3
# --skip-before`. The runs and their figures are in docs/results.md.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
step=${1:?usage: make.sh prepare|train WORK [ARGS]}
work=${2:?usage: make.sh prepare|train WORK [ARGS]}
shift 2
model=$root/models/SmolLM2-135M-Instruct.Q4_1.gguf
mkdir -p "$work"
case $step in
prepare)
    "$root/scripts/adapter/capture.sh" "$work/system"
    python3 "$root/scripts/adapter/data.py" "$work/system" "$work/samples.jsonl"
    "$root/target/release/examples/adapter_tokens" "$model" smollm2 \
        "$work/samples.jsonl" "$work/tokens.jsonl"
    "$root/target/rosvenv/bin/python" "$root/scripts/adapter/pack.py" \
        "$work/tokens.jsonl" "$work/data.npz"
    ;;
train)
    python3 "$root/scripts/adapter/train.py" "$model" "$work/data.npz" "$work/adapter.gguf" "$@"
    ;;
*)
    echo "unknown step $step: prepare or train" >&2
    exit 2
    ;;
esac
