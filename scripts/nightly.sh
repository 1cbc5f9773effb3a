#!/usr/bin/env bash
# Nightly run of one zone (cron): processes what is new or changed, publishes results/<zone>/.
#
#   scripts/nightly.sh ZONE [CONFIGFILE] [extra snakemake arguments...]
#
# - one run at a time: a second start while one is running exits with status 75;
# - a run that was killed (power cut, OOM killer, kill -9) leaves Snakemake's lock behind:
#   it is cleared first (safe, as no other run can hold it), and the incomplete outputs of
#   the killed jobs are redone (rerun-incomplete in profiles/default);
# - --keep-going: a bad block costs only itself; the exit status is then non-zero and
#   results/<zone>/INCOMPLETE.txt plus the QA index name the block and the reason.
set -euo pipefail
zone=${1:?usage: scripts/nightly.sh ZONE [CONFIGFILE] [snakemake arguments...]}
cfg=${2:-}
shift $(( $# >= 2 ? 2 : 1 ))
cd "$(dirname "$0")/.."
if [ -n "${SNAKEMAKE:-}" ]; then read -r -a smk <<< "$SNAKEMAKE"
elif [ -x .venv/bin/snakemake ]; then smk=(.venv/bin/snakemake)
else smk=(snakemake); fi
args=(--cores "${CORES:-2}" --keep-going)
[ -n "$cfg" ] && args+=("--configfile=$cfg")
mkdir -p .snakemake
exec 9>".snakemake/towerpipe-nightly-$zone.lock"
if ! flock -n 9; then
  echo "towerpipe: another run of zone $zone is in progress; nothing done" >&2
  exit 75
fi
"${smk[@]}" "${args[@]}" --unlock -- "results/$zone/" >/dev/null
echo "towerpipe: $(date -u +%FT%TZ) zone $zone: start" >&2
"${smk[@]}" "${args[@]}" "$@" -- "results/$zone/"
