#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian machine: system packages for a real Qt
# window under Xvfb, a virtual environment in .venv with the CPU build of torch
# and the pinned requirements, and sweepedit installed in editable mode.
# A second run on a machine already set up checks and returns in seconds.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

apt_packages=(xvfb xauth libxcb-cursor0 libxkbcommon-x11-0 libxcb-icccm4 libxcb-keysyms1
  libxcb-image0 libxcb-render-util0 libxcb-xinerama0 libxcb-shape0 libgl1 libegl1
  libxrender1 libfontconfig1 libdbus-1-3)
missing=()
for p in "${apt_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "[setup] installing Debian packages: ${missing[*]}"
  sudo_cmd=""; [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

py="${PYTHON:-python3}"
stamp=".venv/.setup-stamp"
want="$(cat requirements.txt pyproject.toml | sha256sum | cut -d' ' -f1)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  exit 0
fi
[ -x .venv/bin/python ] || "$py" -m venv .venv
pip=(.venv/bin/python -m pip -q --disable-pip-version-check)
# torch first and pinned: 2.13.0 is the CPU build that lies on this machine;
# an unpinned torch would pull a multi-GB CUDA build.
"${pip[@]}" install torch==2.13.0
"${pip[@]}" install -r requirements.txt
"${pip[@]}" install --no-deps --no-build-isolation -e .
echo "$want" > "$stamp"
echo "[setup] environment ready in .venv"
