#!/usr/bin/env bash
# Set up jkatana on a fresh Debian 12 machine: system libraries (headless GL for
# the interactive path, Xvfb for the windowed test), a virtual environment in
# .venv, and the package with its test extras. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

SYSTEM_PACKAGES=(libegl1 libegl-mesa0 libgl1 libglx-mesa0 libgl1-mesa-dri libgles2 libosmesa6 libglu1-mesa xvfb xauth libllvm19)
missing=()
for p in "${SYSTEM_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "[setup] installing system packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
# pip's output goes to a log; a failed install stops the set-up (and shows the log's tail).
pip_install() {
  local log; log=$(mktemp)
  if ! .venv/bin/python -m pip install -q "$@" >"$log" 2>&1; then
    grep -v "^WARNING: Location" "$log" | tail -40 >&2
    echo "[setup] pip install $* failed" >&2
    rm -f "$log"; return 1
  fi
  rm -f "$log"
}
pip_install --upgrade pip
pip_install -e ".[test${JKATANA_EXTRAS:+,$JKATANA_EXTRAS}]"
(cd / && "$OLDPWD/.venv/bin/python" -c "import jkatana, jax, pyrender; print('[setup] jkatana', jkatana.__file__, '; jax', jax.__version__)")
