#!/usr/bin/env bash
# Nightly run of one zone (cron): processes what is new or changed, publishes results/<zone>/.
#
#   scripts/nightly.sh ZONE [CONFIGFILE] [extra snakemake arguments...]
#
# - one run per zone: every run takes the zone's run lock (towerpipe.jobs.runlock, held by the
#   Snakefile, whatever started the run); a start while one is alive exits with status 75;
# - a run that was killed (power cut, OOM killer, kill -9) leaves Snakemake's own lock
#   behind: it is cleared (`snakemake --unlock`) only when no towerpipe run is alive, and the
#   incomplete outputs of the killed jobs are redone (rerun-incomplete in workflow/profiles/default);
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
if [ -n "${PYTHON:-}" ]; then py=("$PYTHON")
elif [ -x .venv/bin/python ]; then py=(.venv/bin/python)
else py=(python3); fi
args=(--cores "${CORES:-2}" --keep-going)
[ -n "$cfg" ] && args+=("--configfile=$cfg")
if "${py[@]}" -m towerpipe.jobs.runlock busy "$zone"; then
  echo "towerpipe: another run of zone $zone is in progress; nothing done" >&2
  exit 75
fi
"${py[@]}" -m towerpipe.jobs.runlock if-idle -- "${smk[@]}" "${args[@]}" --unlock -- "results/$zone/"
echo "towerpipe: $(date -u +%FT%TZ) zone $zone: start" >&2
"${smk[@]}" "${args[@]}" "$@" -- "results/$zone/"
