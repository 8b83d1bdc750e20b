#!/usr/bin/env bash
# Build the `ferrosa` binary of an earlier commit (2065ce7 unless told) into
# target/bench/baseline-REV/ferrosa and print its path: the baseline `cargo bench --bench agent`
# measures this tree against (part 5). The commit is checked out in a temporary git
# worktree and built in a target directory of its own, seeded with a copy of this
# tree's built dependencies (llama.cpp among them), so only ferrosa itself is compiled:
# a few minutes on 2 cores, and about 4 GiB of disk while it builds. (Built into this
# tree's own target directory, the old library would take the place of this tree's:
# cargo names a path package's artifacts the same from any checkout.) Beside the binary,
# models/ holds the commit's own model catalog and links to this tree's weights: run
# from that directory, the old binary reads the catalog it knows.
set -euo pipefail
rev=${1:-2065ce7}
cd "$(dirname "$0")/.."
root=$PWD
home="$root/target/bench/baseline-$rev"
out="$home/ferrosa"
if [ -x "$out" ]; then
    echo "$out"
    exit 0
fi
tmp=$(mktemp -d)
trap 'git -C "$root" worktree remove --force "$tmp/ferrosa" >/dev/null 2>&1 || true; rm -rf "$tmp"' EXIT
git worktree add --quiet --detach "$tmp/ferrosa" "$rev"
mkdir -p "$tmp/target/release"
if [ -d target/release/deps ]; then
    cp -r target/release/deps target/release/build target/release/.fingerprint "$tmp/target/release/"
    rm -rf "$tmp"/target/release/deps/*ferrosa* "$tmp"/target/release/.fingerprint/ferrosa-* \
        "$tmp"/target/release/build/ferrosa-*
fi
(cd "$tmp/ferrosa" && CARGO_TARGET_DIR="$tmp/target" cargo build --release --quiet --bin ferrosa)
mkdir -p "$home/models"
git show "$rev:models/catalog.toml" > "$home/models/catalog.toml"
for f in models/*; do
    [ "$(basename "$f")" = catalog.toml ] || ln -sf "$root/$f" "$home/models/"
done
cp "$tmp/target/release/ferrosa" "$out"
echo "$out"
