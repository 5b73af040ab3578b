#!/usr/bin/env bash
# Install what `foliage` needs on a Debian machine, idempotently: apt packages
# (Debian's OpenVDB module, EGL/Mesa for headless GL), a venv at .venv made
# from the system interpreter with --system-site-packages (so Debian's
# pyopenvdb loads), and the project in editable mode with its dev extras.
# Fast when nothing is missing: `make setup` only calls this when
# pyproject.toml is newer than the venv's stamp.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(python3-openvdb python3-venv python3-dev libegl1 libegl-mesa0 libgl1-mesa-dri)
SYSTEM_PYTHON=/usr/bin/python3
VENV=.venv

missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  echo "bootstrap: installing Debian packages: ${missing[*]}"
  if [[ $(id -u) -eq 0 ]]; then SUDO=(); elif command -v sudo >/dev/null; then SUDO=(sudo); else
    echo "bootstrap: need root (or sudo) to install: ${missing[*]}" >&2; exit 2
  fi
  "${SUDO[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

if [[ ! -x $VENV/bin/python ]]; then
  echo "bootstrap: creating $VENV from $SYSTEM_PYTHON (--system-site-packages, for Debian's pyopenvdb)"
  "$SYSTEM_PYTHON" -m venv --system-site-packages "$VENV"
fi

echo "bootstrap: installing foliage-tools and its dependencies into $VENV"
"$VENV/bin/python" -m pip install -q --disable-pip-version-check -e ".[dev]" 2>&1 | grep -v "^WARNING: Location" || true
"$VENV/bin/python" - <<'PY'
import sys
missing = []
for mod in ("pyopenvdb", "pxr.Usd", "numba", "scipy", "embreex", "moderngl", "OpenImageIO", "fast_simplification", "distributed", "bokeh", "foliage_tools.cli.main"):
    try:
        __import__(mod)
    except Exception as exc:  # report every missing piece at once
        missing.append(f"{mod}: {exc}")
if missing:
    sys.exit("bootstrap: these modules do not import in .venv:\n  " + "\n  ".join(missing))
PY
touch "$VENV/.installed"
echo "bootstrap: ready ($VENV)"
