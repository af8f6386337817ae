#!/usr/bin/env bash
# Quick start for transient-mi. Creates ./.venv (if missing), installs the
# package with what it needs (and its test, view and docs extras), then runs:
#   bash run.sh demo [demo options]   the paper's NLOS experiment on the embedded default scene
#   bash run.sh test [pytest options] the test suite (it builds the documentation site too)
#   bash run.sh docs [sphinx options] the documentation site, into docs/_build/html
#   bash run.sh <any transient-mi sub-command and options>
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
cd "$here"
venv="${TRANSIENT_MI_VENV:-$here/.venv}"
py="${PYTHON:-python3}"

if [ ! -x "$venv/bin/python" ]; then
  echo "[run.sh] creating virtual environment $venv" >&2
  "$py" -m venv "$venv"
fi
stamp="$venv/.transient-mi-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "[run.sh] installing transient-mi and its dependencies into $venv" >&2
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  "$venv/bin/python" -m pip install --quiet -e ".[test,view,docs]"
  touch "$stamp"
fi

cmd="${1:-demo}"
[ $# -gt 0 ] && shift
case "$cmd" in
  test)
    # Exit status 5 (no tests collected) is a failure too.
    set +e
    "$venv/bin/python" -m pytest "$@"
    rc=$?
    set -e
    if [ "$rc" -eq 5 ]; then echo "[run.sh] pytest collected no tests: failing" >&2; exit 1; fi
    exit "$rc"
    ;;
  demo)
    exec "$venv/bin/transient-mi" demo "$@"
    ;;
  docs)
    # warnings are errors (-W), every reference must resolve (-n); the reference pages are generated at each build
    out="$here/docs/_build/html"
    "$venv/bin/python" -m sphinx -b html -W --keep-going -n -q -d "$here/docs/_build/doctrees" "$@" docs "$out"
    echo "[run.sh] documentation built: open file://$out/index.html" >&2
    ;;
  *)
    exec "$venv/bin/transient-mi" "$cmd" "$@"
    ;;
esac
