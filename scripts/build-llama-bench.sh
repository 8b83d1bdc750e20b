#!/usr/bin/env bash
# Build upstream llama.cpp's `llama-bench` for `LLAMA_BENCH=… cargo bench --bench runtime`.
#
# The llama.cpp tree comes from the llama-cpp-python source package on PyPI (0.3.36 vendors
# llama.cpp 0c1e57098), so no other network access is needed. Builds in
# target/llama-bench (about 10 minutes on 2 cores) and prints the binary's path.
# Needs python3 with pip, cmake and a C++ compiler (.ci/setup installs them).
set -euo pipefail
cd "$(dirname "$0")/.."
version=0.3.36
dir=target/llama-bench
bin="$dir/llama_cpp_python-$version/vendor/llama.cpp/build/bin/llama-bench"
if [ ! -x "$bin" ]; then
    mkdir -p "$dir"
    if [ ! -f "$dir/llama_cpp_python-$version.tar.gz" ]; then
        python3 -m pip download --quiet --no-deps --no-binary :all: \
            "llama-cpp-python==$version" -d "$dir"
    fi
    tar -xzf "$dir/llama_cpp_python-$version.tar.gz" -C "$dir"
    src="$dir/llama_cpp_python-$version/vendor/llama.cpp"
    cmake -S "$src" -B "$src/build" -DCMAKE_BUILD_TYPE=Release -DLLAMA_CURL=OFF \
        -DLLAMA_BUILD_TESTS=OFF >"$dir/cmake.log"
    cmake --build "$src/build" -j"$(nproc)" --target llama-bench >"$dir/build.log"
fi
realpath "$bin"
