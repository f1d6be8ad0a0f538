#!/usr/bin/env bash
# The whole test suite twice in a row with a CPU hog beside it (issue 23: "the suite passes twice
# in a row on this 2-core machine while a CPU hog runs"), and what the runs left behind in /tmp,
# ~/.ros and /dev/shm.
#
#   bench/ci/loaded_suite.sh [pytest args...]        e.g. bench/ci/loaded_suite.sh -x -q
#
# The hog is stress-ng (--cpu N) when installed, else N busy Python loops; N = the number of CPUs
# (XRCE_HOG_CPUS overrides). Both runs use the README's command (.venv/bin/python -m pytest) from
# the checkout. Prints one line per run (exit code, duration), then the files that appeared in
# /tmp, ~/.ros and /dev/shm during the runs and are still there; exit status 0 only when both
# runs passed and nothing was left. On a machine others use at the same time, their new files in
# /tmp show up in that list too: run it when the machine is otherwise quiet.
set -u
cd "$(dirname "$0")/../.."
PYTHON=.venv/bin/python
[ -x "$PYTHON" ] || { echo "loaded_suite: no $PYTHON: create the venv as README's first line does" >&2; exit 2; }
CPUS=${XRCE_HOG_CPUS:-$(nproc)}
ARGS=("$@")
[ ${#ARGS[@]} -eq 0 ] && ARGS=(-q)

snapshot() {  # every path under the places a run must leave as it found them
    { find /tmp -mindepth 1 -maxdepth 1 2>/dev/null
      find "$HOME/.ros" -mindepth 1 2>/dev/null
      find /dev/shm -mindepth 1 -maxdepth 1 2>/dev/null; } | sort
}

HOG_PIDS=()
start_hog() {
    if command -v stress-ng >/dev/null 2>&1; then
        stress-ng --cpu "$CPUS" --quiet &
        HOG_PIDS+=($!)
    else
        for _ in $(seq "$CPUS"); do
            "$PYTHON" -c "while True: pass" &
            HOG_PIDS+=($!)
        done
    fi
}
stop_hog() {
    for pid in "${HOG_PIDS[@]}"; do kill "$pid" 2>/dev/null; done
    for pid in "${HOG_PIDS[@]}"; do wait "$pid" 2>/dev/null; done
    HOG_PIDS=()
}
trap 'stop_hog; exit 130' INT TERM HUP

BEFORE=$(mktemp -p /tmp xrce-loaded-before.XXXXXX)
snapshot > "$BEFORE"
start_hog
echo "loaded_suite: hog on $CPUS CPU(s) ($(command -v stress-ng >/dev/null && echo stress-ng || echo python loops)); pytest ${ARGS[*]}"
FAILED=0
for run in 1 2; do
    started=$(date +%s)
    "$PYTHON" -m pytest "${ARGS[@]}" > "/tmp/xrce-loaded-run$run.log" 2>&1
    code=$?
    echo "loaded_suite: run $run exit $code in $(( $(date +%s) - started )) s: $(tail -n 1 /tmp/xrce-loaded-run$run.log)"
    if [ $code -eq 0 ]; then
        rm -f "/tmp/xrce-loaded-run$run.log"
    else
        FAILED=1
        grep -E "^(FAILED|ERROR) " "/tmp/xrce-loaded-run$run.log" | sed 's/^/loaded_suite:   /'
        echo "loaded_suite:   whole output kept in /tmp/xrce-loaded-run$run.log"
    fi
done
stop_hog
sleep 2  # children of the last test exit and unlink what they own
# tests/helpers/hygiene.py's detached cleaner removes what the last run's processes held once they are gone
# (up to ~5 s after pytest exits): what is still there after it is left behind.
for _ in $(seq 60); do pgrep -f "hygiene._clean_after" >/dev/null || break; sleep 0.5; done
AFTER=$(mktemp -p /tmp xrce-loaded-after.XXXXXX)
snapshot > "$AFTER"
LEFT=$(comm -13 "$BEFORE" "$AFTER" | grep -v -e "^$BEFORE\$" -e "^$AFTER\$" -e '^/tmp/xrce-loaded-run[12].log$')
rm -f "$BEFORE" "$AFTER"
if [ -n "$LEFT" ]; then
    echo "loaded_suite: left behind:"
    echo "$LEFT" | sed 's/^/loaded_suite:   /'
    FAILED=1
else
    echo "loaded_suite: nothing left in /tmp, ~/.ros or /dev/shm"
fi
exit $FAILED
