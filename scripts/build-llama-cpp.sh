#!/usr/bin/env bash
# Build one of upstream llama.cpp's programs (`llama-bench`, `llama-server`) and print
# its path: the reference for `cargo bench --bench runtime` and the remote engine's peer
# in the tests and benches.
#
# The llama.cpp tree comes from the llama-cpp-python source package on PyPI (0.3.36 vendors
# llama.cpp 0c1e57098), so no other network access is needed. Both programs share one
# build in target/llama-bench (ggml and libllama are built once: about 5 minutes on
# 2 cores). The server is built without its web UI (it would be downloaded) and without
# HTTPS, and with llguidance, so it enforces Lark grammars: llama.cpp's build would clone
# llguidance from GitHub, so the crate's source from crates.io (the version ferrosa's own
# Cargo.lock pins, already in cargo's registry after `cargo build`) is put where that
# clone would go. On x86-64 it is built without AMX, as ferrosa's own llama.cpp is
# (.cargo/config.toml): with GGML_NATIVE on a CPU that has AMX, ggml's AMX kernel dies on
# the first decode of the default model (SIGILL or SIGSEGV in tinygemm_kernel_amx, measured
# here), and the speed reference must use the instruction set ferrosa uses. A build made
# with other flags is rebuilt. Needs python3 with pip, cmake, a C++ compiler and cargo
# (.ci/setup).
set -euo pipefail
target=${1:?usage: scripts/build-llama-cpp.sh llama-bench|llama-server}
case "$target" in
    llama-bench | llama-server) ;;
    *) echo "unknown program '$target': llama-bench or llama-server" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/.."
version=0.3.36
dir=target/llama-bench
src="$dir/llama_cpp_python-$version/vendor/llama.cpp"
bin="$src/build/bin/$target"
flags=""
[ "$(uname -m)" = x86_64 ] && flags="-mno-amx-tile -mno-amx-int8 -mno-amx-bf16"
stamp="$src/build/ferrosa-flags"
if [ -d "$src/build" ] && [ "$(cat "$stamp" 2>/dev/null)" != "flags: $flags" ]; then
    rm -rf "$src/build"
fi
if [ ! -x "$bin" ]; then
    mkdir -p "$dir"
    if [ ! -f "$dir/llama_cpp_python-$version.tar.gz" ]; then
        python3 -m pip download --quiet --no-deps --no-binary :all: \
            "llama-cpp-python==$version" -d "$dir"
    fi
    [ -d "$src" ] || tar -xzf "$dir/llama_cpp_python-$version.tar.gz" -C "$dir"
    # llguidance from crates.io instead of a git clone.
    llg_version=$(awk '/^name = "llguidance"$/ { getline; gsub(/[^0-9.]/, ""); print; exit }' Cargo.lock)
    llg_src=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/"llguidance-$llg_version" 2>/dev/null | head -1)
    if [ -z "$llg_src" ]; then
        (cargo fetch --quiet >/dev/null) || true
        llg_src=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/"llguidance-$llg_version" | head -1)
    fi
    sed -i -e 's|^\( *\)GIT_REPOSITORY https://github.com/guidance-ai/llguidance|\1DOWNLOAD_COMMAND ""|' \
        -e '/^ *GIT_TAG [0-9a-f]\{40\}$/d' "$src/common/CMakeLists.txt"
    mkdir -p "$src/build/llguidance"
    [ -d "$src/build/llguidance/source" ] || cp -r "$llg_src" "$src/build/llguidance/source"
    cmake -S "$src" -B "$src/build" -DCMAKE_BUILD_TYPE=Release -DLLAMA_CURL=OFF \
        -DLLAMA_BUILD_TESTS=OFF -DLLAMA_USE_PREBUILT_UI=OFF -DLLAMA_BUILD_UI=OFF \
        -DLLAMA_OPENSSL=OFF -DLLAMA_LLGUIDANCE=ON \
        -DCMAKE_C_FLAGS="$flags" -DCMAKE_CXX_FLAGS="$flags" >"$dir/cmake.log"
    echo "flags: $flags" >"$stamp"
    cmake --build "$src/build" -j"$(nproc)" --target "$target" >"$dir/build-$target.log" 2>&1 || {
        tail -30 "$dir/build-$target.log" >&2
        exit 1
    }
fi
realpath "$bin"
