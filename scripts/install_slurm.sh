#!/usr/bin/env bash
# Install a single-machine SLURM (Debian 12 slurm-wlm + munge) for the cluster test
# (tests/workflow/test_slurm.py): `make test` runs this, then scripts/slurm_local.sh starts it.
# Idempotent; needs root (or sudo) and Debian's apt. Elsewhere it says why and exits 0:
# the SLURM test then skips with that reason. Where no /etc/slurm/slurm.conf exists it writes
# the single-node one (scripts/slurm_local.sh conf): without one, `scontrol` retries for a
# minute, and the SLURM executor plugin calls it whenever Snakemake starts (10 s a start).
set -euo pipefail
here=$(dirname "$0")
conf() { [ -s /etc/slurm/slurm.conf ] || [ "$(id -u)" != 0 ] || bash "$here/slurm_local.sh" conf; }
if command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v munged >/dev/null; then
  conf; exit 0
fi
if ! command -v apt-get >/dev/null; then
  echo "install_slurm: no apt-get here; install slurm-wlm and munge to run the SLURM test" >&2; exit 0
fi
sudo=""
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null && sudo -n true 2>/dev/null; then sudo="sudo -n"
  else echo "install_slurm: not root and no sudo; the SLURM test will be skipped" >&2; exit 0; fi
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -q >/dev/null
$sudo apt-get install -y -q --no-install-recommends slurm-wlm munge >/dev/null
conf
