#!/usr/bin/env bash
# Build upstream llama.cpp's `llama-bench` for `LLAMA_BENCH=… cargo bench --bench runtime`
# and print its path (see build-llama-cpp.sh).
exec "$(dirname "$0")/build-llama-cpp.sh" llama-bench
