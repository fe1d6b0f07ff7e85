#!/usr/bin/env bash
# Run every bundled project into OUTDIR/<folder>_<project>/ (for tests/regression/compare_runs.py).
#   tests/regression/run_fixtures.sh OUTDIR [PATTERN]
set -uo pipefail
cd "$(dirname "$0")/../.."
out=${1:?usage: run_fixtures.sh OUTDIR [PATTERN]}
pat=${2:-}
mkdir -p "$out"
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
for p in $(find fixtures -name '*.toml' -not -path '*/tests/*' | sort); do
  [[ -n "$pat" && "$p" != *$pat* ]] && continue
  name=$(echo "$p" | sed 's#fixtures/##; s#/#_#g; s#\.toml$##')
  rm -rf "$out/$name"
  start=$(date +%s.%N)
  .venv/bin/baarda run "$p" --out "$out/$name" > "$out/$name.log" 2>&1
  rc=$?
  echo "$name rc=$rc $(python3 -c "import time; print(round(time.time() - $start, 1))") s"
done
