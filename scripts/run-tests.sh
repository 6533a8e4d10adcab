#!/usr/bin/env bash
# Run the whole test suite on a fresh machine: own virtual environment, the project
# with its test extra, the Debian packages headless Qt needs, pytest under Xvfb.
#
#   bash scripts/run-tests.sh            # everything
#   bash scripts/run-tests.sh -k motion  # extra arguments go to both pytest runs
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

VENV="${EDGECME_VENV:-.venv}"
PYTHON="${PYTHON:-python3}"

# 1. Debian packages for a virtual X display and Qt's xcb platform (see TESTING.md).
DEB_PACKAGES=(xvfb xauth libegl1 libgl1 libopengl0 libdbus-1-3 libfontconfig1
  libxkbcommon-x11-0 libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-randr0
  libxcb-render-util0 libxcb-xinerama0 libxcb-xinput0 libxcb-xfixes0 libxcb-shape0
  libxcb-cursor0)
missing=()
for pkg in "${DEB_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" \
    || missing+=("$pkg")
done
if ((${#missing[@]})); then
  echo "run-tests: installing Debian packages: ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi

# 2. A virtual environment with the project and its test extra.
if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e ".[test]"

# 3. pytest twice: engine + offscreen widget tests (no display), then the full-viewer
#    tests on a virtual X display (pytest-xvfb starts Xvfb). Exit 5 = nothing collected.
run_pytest() {
  local status=0
  "$VENV/bin/python" -m pytest "$@" || status=$?
  if [ "$status" -eq 5 ]; then
    echo "run-tests: no tests collected for: $*"
    status=0
  fi
  return "$status"
}
mkdir -p test-artifacts
QT_QPA_PLATFORM=offscreen run_pytest -m "not viewer" --no-xvfb "$@"
run_pytest -m viewer "$@"
echo "run-tests: all passed"
