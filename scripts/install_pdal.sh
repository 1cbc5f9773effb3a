#!/usr/bin/env bash
# Install the PDAL command-line tool (>= 2.2), idempotently.
#
# * A working `pdal` >= 2.2 already on PATH (conda, OSGeo4W, a distribution
#   package) -> nothing to do.
# * Debian 12 (bookworm), which has no PDAL package -> Debian 11 (bullseye)'s
#   pdal 2.2.0 beside bookworm, with an apt preferences pin (priority 100) so
#   nothing else is taken from bullseye, plus the four bullseye libraries that
#   keep libgdal/PROJ consistent (without them: "undefined symbol" in
#   libgdal.so.28, or a segfault at exit, rc 139).
# * Anything else -> print how to get PDAL and exit 1.
set -euo pipefail

pdal_ok() {
  command -v pdal >/dev/null 2>&1 || return 1
  local v
  v=$(pdal --version 2>/dev/null | grep -oE '[0-9]+\.[0-9]+(\.[0-9]+)?' | head -n1) || return 1
  [ -n "$v" ] || return 1
  python3 - "$v" <<'PY'
import sys
major, minor = (int(p) for p in sys.argv[1].split(".")[:2])
sys.exit(0 if (major, minor) >= (2, 2) else 1)
PY
}

if pdal_ok; then
  echo "install_pdal: $(pdal --version 2>/dev/null | grep -m1 -oE 'pdal [0-9.]+.*' || echo pdal) already works; nothing to do"
  exit 0
fi

. /etc/os-release 2>/dev/null || true
if [ "${ID:-}" != "debian" ] || [ "${VERSION_CODENAME:-}" != "bookworm" ]; then
  cat >&2 <<MSG
install_pdal: no working 'pdal' (>= 2.2) on PATH and this is not Debian 12, so
nothing was installed. Get PDAL one of these ways, then rerun:
  - conda/mamba:  mamba install -c conda-forge pdal
  - Ubuntu >= 22.04 / Debian >= 13:  apt-get install pdal
  - macOS:  brew install pdal
MSG
  exit 1
fi

SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"

$SUDO tee /etc/apt/sources.list.d/towerpipe-bullseye.list >/dev/null <<'LIST'
# added by towerpipe scripts/install_pdal.sh: PDAL 2.2 from Debian 11 (pinned, see preferences)
deb http://deb.debian.org/debian bullseye main
LIST
$SUDO tee /etc/apt/preferences.d/towerpipe-bullseye >/dev/null <<'PREF'
# Only what is named explicitly is taken from bullseye.
Package: *
Pin: release n=bullseye
Pin-Priority: 100
PREF

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends --allow-downgrades \
  pdal \
  libdap27=3.20.7-6 libdapclient6v5=3.20.7-6 \
  libgeotiff5=1.6.0-1 libspatialite7=5.0.1-2 >/dev/null

if ! pdal_ok; then
  echo "install_pdal: pdal was installed but 'pdal --version' fails; see apt output above" >&2
  exit 1
fi
echo "install_pdal: installed $(pdal --version 2>/dev/null | grep -m1 -oE 'pdal [0-9.]+' || echo pdal)"
