#!/usr/bin/env bash
# The Python package as a user gets it: a fresh virtual environment, `pip install` of
# python/ with its test extras (the command docs/python.md gives, plus pytest, scipy, h5py,
# pandas and matplotlib), then python/tests, which compare the package with the command line
# $1 (an nlsim binary), scipy and closed forms, and run the guide's worked script.
set -euo pipefail
cd "$(dirname "$0")/.."
nlsim_bin="$(realpath "$1")"
venv="${CARGO_TARGET_DIR:-target}/py-venv"
rm -rf "$venv"
if ! python3 -m venv "$venv" >/dev/null 2>&1; then
  echo "python-tests: python3 -m venv failed; install the venv module (Debian: sudo apt-get install -y python3-venv)" >&2
  exit 1
fi
"$venv/bin/pip" install -q --disable-pip-version-check "./python[test]"
NLSIM_BIN="$nlsim_bin" "$venv/bin/python" -m pytest -q -p no:cacheprovider python/tests
