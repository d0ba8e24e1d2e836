#!/usr/bin/env bash
# Prints a Python interpreter that can import h5py (the one on PATH, else Debian's), or stops
# with the command that installs it.
for py in python3 /usr/bin/python3; do
  if command -v "$py" >/dev/null 2>&1 && "$py" -c 'import h5py' 2>/dev/null; then
    command -v "$py"
    exit 0
  fi
done
echo "no Python with h5py: run sudo apt-get install -y python3-h5py (scripts/ensure-deps.sh --test does)" >&2
exit 1
