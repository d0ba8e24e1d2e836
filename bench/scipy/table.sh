#!/usr/bin/env bash
# The reduction table of BENCHMARKS.md in one command: for each row, `nlsim modes` on the
# bracket fixture and scipy's eigsh with a CHOLMOD Cholesky inverse (one thread) on the same
# matrices (written by `nlsim export`), back to back, each a whole process under
# /usr/bin/time. Prints a Markdown table: wall / CPU (user + system) / peak RSS for each side,
# and eigsh's own time without reading the Matrix Market files.
#
#   bench/scipy/table.sh                     # rows 4:50 4:200 6:50 6:200 9:50
#   ROWS="6:50" bench/scipy/table.sh         # refinement:modes pairs
#   NLSIM=path/to/nlsim NLSIM_ARGS="--threads 1" bench/scipy/table.sh
#
# Needs a release build (`cargo build --release --features cli --bin nlsim`), GNU time
# (`apt install time`), and python3 with numpy, scipy and scikit-sparse (see the header of
# eigsh_reference.py). Refinement 9 (307 395 DOFs) needs about 6 GB and several minutes per
# side; its matrices take 1.5 GB in the temporary directory.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
nlsim=${NLSIM:-$here/../../target/release/nlsim}
python=${PYTHON:-python3}
rows=${ROWS:-"4:50 4:200 6:50 6:200 9:50"}
nlsim_args=${NLSIM_ARGS:-}

[ -x "$nlsim" ] || {
    echo "no nlsim at $nlsim: run cargo build --release --features cli --bin nlsim" >&2
    exit 1
}
[ -x /usr/bin/time ] || {
    echo "GNU time is missing: apt install time" >&2
    exit 1
}
"$python" -c "import scipy, sksparse.cholmod" 2> /dev/null || {
    echo "$python lacks scipy or scikit-sparse (see bench/scipy/eigsh_reference.py)" >&2
    exit 1
}

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# "wall / CPU / RSS" from a /usr/bin/time -f "%e %U %S %M" file.
fmt() {
    awk '{ printf "%.1f s / %.1f s / %.2f GB", $1, $2 + $3, $4 / 1048576 }' "$1"
}

echo "| DOFs, modes | nlsim wall / CPU / peak RSS | eigsh + CHOLMOD wall / CPU / peak RSS (eigsh alone) |"
echo "|---|---|---|"
for row in $rows; do
    r=${row%:*}
    k=${row#*:}
    dir=$work/r$r
    if [ ! -d "$dir" ]; then
        rm -rf "$work"/r*
        "$nlsim" export "bracket:refinement=$r" "$dir" > /dev/null
    fi
    dofs=$(awk '!/^%/ { print $1; exit }' "$dir/K.mtx")
    # shellcheck disable=SC2086
    /usr/bin/time -f "%e %U %S %M" -o "$work/nlsim.time" \
        "$nlsim" modes "bracket:refinement=$r" --count "$k" $nlsim_args > /dev/null
    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 /usr/bin/time -f "%e %U %S %M" -o "$work/eigsh.time" \
        "$python" "$here/eigsh_reference.py" "$dir" "$k" --cholmod > "$work/eigsh.out"
    alone=$(awk '/^eigsh k=/ { print $3 }' "$work/eigsh.out")
    echo "| $dofs, $k | $(fmt "$work/nlsim.time") | $(fmt "$work/eigsh.time") ($alone s) |"
done
