#!/usr/bin/env bash
# Set up (idempotent) and run the main job: the app on the bundled example shape.
# With no display, the same abstraction runs headless and writes its outputs to out/:
# the parameter file, the swept mesh and a rendered picture.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
example="resources/examples/cactus.off"
if [ -n "${DISPLAY:-}" ] && [ "${SWEEPEDIT_HEADLESS:-0}" != "1" ]; then
  exec .venv/bin/sweepedit "${1:-$example}"
fi
mkdir -p out
shape="${1:-$example}"
name="$(basename "${shape%.*}")"
.venv/bin/sweepedit fit "$shape" -o "out/$name.json" --mesh "out/$name.glb" \
  --screenshot "out/$name.png"
echo "outputs: out/$name.json out/$name.glb out/$name.png"
