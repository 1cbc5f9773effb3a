#!/usr/bin/env bash
# Install headless Chromium (the QA pages' browser test, tests/products/test_qa_browser.py, and the
# screenshots of docs/img), idempotently.
#
# * `chromium` (or TOWERPIPE_CHROMIUM) already runs -> nothing to do.
# * Debian/Ubuntu with root or sudo -> `apt-get install chromium` (Debian's own package).
# * Anything else -> say so and exit 0: the browser test then skips and names the reason.
set -euo pipefail

works() {
  local bin="${TOWERPIPE_CHROMIUM:-$(command -v chromium || command -v chromium-browser || true)}"
  [ -n "$bin" ] && "$bin" --headless --no-sandbox --disable-gpu --version >/dev/null 2>&1
}

if works; then
  echo "install_chromium: $(${TOWERPIPE_CHROMIUM:-chromium} --version 2>/dev/null || echo chromium) already works; nothing to do"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    SUDO="sudo"
  else
    echo "install_chromium: not root and no sudo: install chromium yourself (the browser test skips until then)" >&2
    exit 0
  fi
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "install_chromium: no apt-get here: install chromium yourself (the browser test skips until then)" >&2
  exit 0
fi

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null

if ! works; then
  echo "install_chromium: chromium was installed but does not start; see apt output above" >&2
  exit 1
fi
echo "install_chromium: installed $(chromium --version 2>/dev/null || echo chromium)"
