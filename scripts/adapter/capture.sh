#!/usr/bin/env bash
# Capture the system message the agent shows the model on each of the project's robots
# (the robot prompt and the tools it lists), as the agent renders it: the built-in sim,
# and the arm peer (tests/peers/arm_peer.py) over DDS. Each goes to OUT/<robot>.txt.
# Runs in a loopback-only network namespace, like the tests.
#
#   scripts/adapter/capture.sh OUT
set -euo pipefail
out=${1:?usage: capture.sh OUT}
root=$(cd "$(dirname "$0")/../.." && pwd)
mkdir -p "$out"
bin=$root/target/release/ferrosa
py=$root/target/rosvenv/bin/python
log=$(mktemp)
trap 'rm -f "$log"' EXIT

# The prompt log prints each rendered prompt; the system message is the text between the
# first "<|im_start|>system" and its "<|im_end|>".
system_of() {
    python3 - "$1" <<'PY'
import re, sys
text = open(sys.argv[1], encoding="utf-8").read()
m = re.search(r"<\|im_start\|>system\n(.*?)<\|im_end\|>", text, re.S)
if not m:
    sys.exit("no system message in the prompt log")
sys.stdout.write(m.group(1))
PY
}

unshare -n bash -c '
ip link set lo up
export XDG_DATA_HOME=$(mktemp -d) ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export FERROSA_LOG=warn,ferrosa::prompt=debug,rustdds=error NO_COLOR=1
timeout -k 5 120 "$0" --prompt-cache off ask --robot sim --yes "list the nodes" >"$1" 2>&1
' "$bin" "$log"
system_of "$log" >"$out/sim.txt"

unshare -n bash -c '
ip link set lo up
export XDG_DATA_HOME=$(mktemp -d) ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
timeout -k 5 120 "$2" "$3/tests/peers/arm_peer.py" serve >/dev/null 2>&1 &
sleep 6
export FERROSA_LOG=warn,ferrosa::prompt=debug,rustdds=error NO_COLOR=1
timeout -k 5 120 "$0" --prompt-cache off ask --robot ros2 --prompt "$3/prompts/arm.toml" --yes "list the nodes" >"$1" 2>&1
kill %1 2>/dev/null; wait
' "$bin" "$log" "$py" "$root"
system_of "$log" >"$out/arm.txt"
wc -c "$out"/*.txt
