#!/usr/bin/env bash
# Run the README's test command beside N busy processes (default 3), the check that no
# test's verdict depends on the machine's load (docs/getting-started.md, "The tests
# beside busy processes"). Usage: bash scripts/suite-beside-busy.sh [N] [pytest args...]
# The busy loops share one session (setsid), and so one scheduler group under Linux's
# autogroup; each is a full CPU-bound process. They are stopped when the run ends,
# whatever its outcome; the exit status is pytest's.
set -u
n=${1:-3}
shift || true
setsid sh -c "for i in \$(seq $n); do sh -c 'while :; do :; done' & done; wait" &
busy=$!
trap 'kill -- -"$busy" 2>/dev/null' EXIT INT TERM
echo "$(date -u +%FT%TZ) $n busy processes started (session $busy)"
python -m pytest -q -n auto --dist loadfile --max-worker-restart=0 "$@"
status=$?
echo "$(date -u +%FT%TZ) exit $status; load $(cut -d' ' -f1-3 /proc/loadavg)"
exit $status
