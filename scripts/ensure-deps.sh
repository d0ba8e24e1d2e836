#!/usr/bin/env bash
# Installs what a fresh Debian/Ubuntu machine lacks to build and test nlsim, or stops with the
# exact command to run. Called by `make demo` and `make test`.
set -euo pipefail

# Debian packages the build needs: a C compiler for mimalloc, the HDF5 library (with
# pkg-config to find it) for the result files, and a TrueType font for the text of PNG plots.
APT_PACKAGES=(gcc libc6-dev libhdf5-dev pkg-config fonts-dejavu-core)
# `make test` also reads every result file with h5py, runs the batch tool on a real
# single-node SLURM (scripts/slurm-e2e.sh), opens the report page in headless chromium and
# installs the Python package into a fresh virtual environment (scripts/python-tests.sh).
if [ "${1:-}" = "--test" ]; then
  APT_PACKAGES+=(python3-h5py python3-pip python3-venv slurm-wlm munge chromium)
fi

say() { printf 'nlsim setup: %s\n' "$*" >&2; }

if ! command -v cargo >/dev/null 2>&1; then
  say "Rust is not installed. Install it with:"
  say "  curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y && . \"\$HOME/.cargo/env\""
  exit 1
fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if ! command -v apt-get >/dev/null 2>&1; then
    say "missing system packages: ${missing[*]} (no apt-get here: install their equivalents)"
    exit 1
  fi
  if [ "$(id -u)" -eq 0 ]; then
    say "installing ${missing[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    say "installing ${missing[*]} with sudo"
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    say "missing system packages. Run:"
    say "  sudo apt-get update && sudo apt-get install -y ${missing[*]}"
    exit 1
  fi
fi

# Disk: a cold `make test` writes about 2.8 GB under the target directory (more with
# incremental caches), `make demo` about 1 GB more. Warn before a build would stop halfway
# with "No space left on device".
target="${CARGO_TARGET_DIR:-target}"
probe="$target"
while [ ! -e "$probe" ]; do probe="$(dirname "$probe")"; done
need_mb=1500
[ "${1:-}" = "--test" ] && need_mb=4000
have_mb=$(df -Pm "$probe" | awk 'NR == 2 { print $4 }')
used_mb=0
[ -d "$target" ] && used_mb=$(du -sm "$target" 2>/dev/null | cut -f1)
if [ -n "$have_mb" ] && [ $((have_mb + used_mb)) -lt "$need_mb" ]; then
  say "warning: $have_mb MB free on the disk of $target (which holds $used_mb MB); a cold build"
  say "  needs about $need_mb MB. Free space, or point CARGO_TARGET_DIR at a larger disk."
fi

# pyNastran and pyuff (PyPI) for `make test`: the independent writers and readers of the DMIG
# files the FE-matrix readers are checked on and of the universal files nlsim reads and
# writes, installed into the Python that has h5py.
if [ "${1:-}" = "--test" ]; then
  py="$(scripts/find-h5py.sh)"
  for pkg in pyNastran==1.4.1 pyuff==2.5.8; do
    mod="${pkg%%==*}"
    if ! "$py" -c "import $mod" 2>/dev/null; then
      say "installing $pkg (PyPI) for $py"
      "$py" -m pip install -q --break-system-packages "$pkg" 2>/dev/null \
        || "$py" -m pip install -q "$pkg" \
        || { say "could not install $pkg. Run: $py -m pip install --break-system-packages $pkg"; exit 1; }
    fi
  done
fi

# rustfmt and clippy for `make test`.
if [ "${1:-}" = "--test" ]; then
  for comp in rustfmt clippy; do
    if ! cargo "${comp/rustfmt/fmt}" --version >/dev/null 2>&1; then
      if command -v rustup >/dev/null 2>&1; then
        say "adding the $comp component"
        rustup component add "$comp"
      else
        say "cargo $comp is missing. Run: rustup component add $comp"
        exit 1
      fi
    fi
  done
fi
