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
want="$(cat requirements.txt pyproject.toml scripts/requirements-blender.txt | sha256sum | cut -d' ' -f1)"
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

# Blender's bpy for .blend export, in an environment of its own (.venv-blender): it pins
# numpy < 2. Optional: where it cannot be installed, set-up goes on without it.
blender_env() {
  if ! "$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "[setup] Blender export unavailable: bpy 5.0 needs Python 3.11, $py is $("$py" -V 2>&1)"
    return 0
  fi
  [ -x .venv-blender/bin/python ] || "$py" -m venv .venv-blender || {
    echo "[setup] Blender export unavailable: could not create .venv-blender"; return 0; }
  if ! .venv-blender/bin/python -m pip -q --disable-pip-version-check install \
      -r scripts/requirements-blender.txt >/tmp/sweepedit-setup-bpy.log 2>&1; then
    echo "[setup] Blender export unavailable: installing bpy failed" \
      "($(tail -n 1 /tmp/sweepedit-setup-bpy.log))"
  fi
  return 0
}
blender_env
echo "$want" > "$stamp"
echo "[setup] environment ready in .venv"
