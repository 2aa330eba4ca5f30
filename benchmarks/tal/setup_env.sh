#!/usr/bin/env bash
# The SEPARATE environment for benchmarks/tal/compare.py: y-tal 0.20 (pins numpy < 2, so it cannot live in
# datagen's numpy-2 environment) and mitransient with its Mitsuba / Dr.Jit, in their own venv.
#
#   bash benchmarks/tal/setup_env.sh            # venv at /opt/venvs/tal-bench (or $TAL_BENCH_VENV)
#
# mitransient's LLVM variants need Debian's libllvm19; Dr.Jit finds it through DRJIT_LIBLLVM_PATH, which this
# script writes into $VENV/env.sh (compare.py finds the library by itself). tal keeps its settings in
# ~/.tal.conf; compare.py gives tal a private HOME under benchmarks/tal/out/, so nothing here touches yours.
set -euo pipefail

VENV="${TAL_BENCH_VENV:-/opt/venvs/tal-bench}"
PYTHON="${PYTHON:-python3}"

# versions the benchmark was run with (docs/tal.md)
PINS=("y-tal==0.20.0" "mitransient==1.3.1" "mitsuba==3.9.1" "drjit==1.5.0"
      "pyfftw==0.15.1")   # pyfftw: tal.reconstruct.pf imports it (y-tal does not declare it; bench_recon.py)

find_llvm() {
    for p in /usr/lib/llvm-19/lib/libLLVM.so.1 /usr/lib/llvm-19/lib/libLLVM.so \
             /usr/lib/*-linux-gnu/libLLVM-19.so /usr/lib/*-linux-gnu/libLLVM.so.19.1; do
        [ -f "$p" ] && { echo "$p"; return 0; }
    done
    return 1
}

if ! LLVM="$(find_llvm)"; then
    if [ "$(id -u)" = 0 ]; then
        apt-get update -qq
        apt-get install -y -qq libllvm19
    else
        echo "libLLVM 19 is missing: run 'sudo apt-get install -y libllvm19' and retry" >&2
        exit 1
    fi
    LLVM="$(find_llvm)"
fi

"$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q "${PINS[@]}"

cat > "$VENV/env.sh" <<EOF
# source this before using tal / mitransient from $VENV
export DRJIT_LIBLLVM_PATH="$LLVM"
EOF

# smoke test: Mitsuba's LLVM variant, mitransient's plugins, tal's reader
DRJIT_LIBLLVM_PATH="$LLVM" "$VENV/bin/python" - <<'EOF'
import mitsuba as mi
mi.set_variant("llvm_ad_mono")
import mitransient, tal, numpy
print(f"mitsuba {mi.__version__}, mitransient {mitransient.__version__}, y-tal {tal.__version__}, "
      f"numpy {numpy.__version__}: ok")
EOF
echo "tal venv ready at $VENV (DRJIT_LIBLLVM_PATH=$LLVM)"
