#!/usr/bin/env bash
# Create benchmarks/.peers-venv: the benchmark's own environment, with the peer libraries from PyPI
# and magfit installed editable from this checkout.
#
# The peers pin their own dependencies (magyc needs numpy<2, jax and gtsam), which must not leak into
# magfit's development venv: hence a separate venv. Re-running the script updates it in place.
#
# Usage: bash benchmarks/setup_peers.sh        (from anywhere; PYTHON=python3.11 to choose the interpreter)
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
venv="$here/.peers-venv"
python="${PYTHON:-python3}"

if [ ! -x "$venv/bin/python" ]; then
    "$python" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --upgrade pip
# The peers a user would pick instead of magfit (see benchmarks/README.md for what each one fits).
# Installed one by one so that one that cannot be installed does not keep the others out: the
# benchmark records a missing peer in its table instead of failing.
for peer in "magyc==1.0.0" "magcal==1.0.1" "circuitpython-mag-cal==1.4.1"; do
    if ! "$venv/bin/python" -m pip install --quiet "$peer"; then
        echo "setup_peers.sh: could not install $peer; the benchmark will report it as unavailable" >&2
    fi
done
"$venv/bin/python" -m pip install --quiet -e "$root"
"$venv/bin/python" -m pip list 2>/dev/null | grep -i -E "^(magfit|magyc|magcal|circuitpython-mag-cal|numpy|scipy|jax|gtsam) " || true
