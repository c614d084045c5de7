#!/usr/bin/env bash
# Refresh constraints.txt against the newest releases:
#   bash scripts/refresh_constraints.sh              # install, run the tests, then write
#   bash scripts/refresh_constraints.sh --no-test    # install and write, no tests
#   bash scripts/refresh_constraints.sh --out FILE   # write FILE instead
# A new virtual environment in a temporary folder (interpreter: $PYTHON, default
# python3) takes `pip install -e ".[test]"` with no constraints, so pip picks the
# newest releases pyproject.toml's ranges allow; scripts/test.sh runs there, and
# only if it passes are that environment's versions written: every package but pip
# and rhythmic_jax, setuptools included (torch needs a newer one than a new venv
# brings), local version labels such as torch's +cpu dropped (either wheel of the
# release satisfies the pin).
set -euo pipefail
cd "$(dirname "$0")/.."

usage="usage: bash scripts/refresh_constraints.sh [--no-test] [--out FILE]"
test_first=1
out=constraints.txt
while [ $# -gt 0 ]; do
  case "$1" in
    --no-test) test_first=0 ;;
    --out)
      [ $# -ge 2 ] || { echo "error: --out needs a file name; $usage" >&2; exit 2; }
      out="$2"; shift ;;
    -h|--help) echo "$usage"; exit 0 ;;
    *) echo "error: unknown argument '$1'; $usage" >&2; exit 2 ;;
  esac
  shift
done

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
"${PYTHON:-python3}" -m venv "$tmp/venv"
# shellcheck disable=SC1091
. "$tmp/venv/bin/activate"
pip install -e ".[test]"
if [ "$test_first" = 1 ]; then
  bash scripts/test.sh
fi

{
  pyver="$(python -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
  if [ "$test_first" = 1 ]; then
    echo "# The exact versions the test suite passed with, on Python $pyver, for"
  else
    echo "# The newest versions on Python $pyver (--no-test: not yet tested), for"
  fi
  echo '# `pip install -c constraints.txt -e ".[test]"` (README set-up, .ci/run).'
  echo "# pyproject.toml keeps ranges; refresh: bash scripts/refresh_constraints.sh"
  pip freeze --all --exclude-editable \
    | grep -v -i -E '^(rhythmic[-_]jax|pip)([=@ ]|$)' \
    | sed -E 's/^([^=]+==[^+;]+)\+[A-Za-z0-9.]+/\1/'
} > "$tmp/constraints.txt"
mv "$tmp/constraints.txt" "$out"
echo "wrote $out ($(grep -c '==' "$out") pins)"
