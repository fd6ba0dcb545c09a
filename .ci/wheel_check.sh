#!/usr/bin/env bash
# The wheel, installed on its own (not editable), runs the rover and PushAround outside the checkout.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$repo/.venv/bin/python" -m pip wheel --quiet --no-deps --wheel-dir "$work/dist" "$repo"
python3 -m venv "$work/venv"
"$work/venv/bin/python" -m pip install --quiet --upgrade pip
"$work/venv/bin/python" -m pip install --quiet -c "$repo/constraints.txt" "$work"/dist/jaxplan-*.whl
cd "$work"
"$work/venv/bin/jaxplan" rover --routes 1 --no-render --out "$work/rover"
"$work/venv/bin/jaxplan" pusharound --no-execute --time-limit 30 --out "$work/pusharound"
test -s "$work/rover/summary.json"
test -s "$work/pusharound/result.json"
echo "wheel check: the installed wheel ran the rover and PushAround outside the checkout"
