#!/bin/sh
# `make test` with CPU hogs running (issue 30: "make test passes with 4 hogs running"); `make test-loaded` runs it.
# The hogs (tests/hogs.py) are busy loops at the suite's own priority, each ending itself at its deadline and
# killed with this script (by pid; the kernel also kills them if this shell's python dies first).
#   GVT_HOGS=4 (how many)   GVT_HOGS_SECONDS=5400 (each hog's own deadline)   PYTHON=.venv/bin/python
set -u
cd "$(dirname "$0")/.." || exit 2
n=${GVT_HOGS:-4}
py=${PYTHON:-.venv/bin/python}
"$py" tests/hogs.py "$n" "${GVT_HOGS_SECONDS:-5400}" &
hogs=$!
trap 'kill "$hogs" 2>/dev/null; wait "$hogs" 2>/dev/null' EXIT
trap 'exit 130' INT TERM
start=$(date +%s)
${MAKE:-make} test
rc=$?
echo "make test with $n hogs running: exit $rc in $(( $(date +%s) - start )) s (load now: $(cut -d' ' -f1-4 /proc/loadavg))"
exit $rc
