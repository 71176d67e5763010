#!/usr/bin/env bash
# scripts/test_vcan.sh - what `make test-vcan` runs: the HIL tests (pytest -m vcan, tests/hil)
# over SocketCAN vcan0, natively when vcan0 exists and opens, otherwise inside the QEMU VM of
# ../shared/tools/canvm (setup_vm.sh every time: it skips finished steps; the project dir is
# mounted and run with PYTHONPATH=.; package versions pinned to this venv's).
#
# Outside CI it may skip (exit 0) with the reason; with CI=true it must run them and fails if
# it cannot, or if any test skipped or none passed. Last line: "vcan: N passed, M failed".
#
# The reference firmware's node (tests/hil/test_vcan_firmware.py) is built first, on the host,
# statically against SHARED_DIR/third_party (make -C firmware node), so it runs in the VM too.
#
# Environment: PYTHON (default .venv/bin/python), SHARED_DIR (default ../shared), CANVM_DIR
# (default $SHARED_DIR/tools/canvm), CANIMUCAL_VCAN (default vcan0), VM_TIMEOUT (default
# 1500 s), PYTEST_ADDOPTS (handed into the VM too, e.g. -k case3).
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
SHARED=${SHARED_DIR:-../shared}
CANVM=${CANVM_DIR:-$SHARED/tools/canvm}
VCAN=${CANIMUCAL_VCAN:-vcan0}
IS_CI=false
case "${CI:-}" in true|1|yes) IS_CI=true;; esac
PYTEST=(-m pytest -q -p no:cacheprovider -m vcan tests/hil -rfEsP --durations=8)
LOG=$(mktemp /tmp/canimucal-vcan.XXXXXX)
trap 'rm -f "$LOG"' EXIT
t0=$(date +%s)

give_up() {  # reason
  if $IS_CI; then
    echo "vcan: cannot run the HIL tests: $1" >&2
    echo "vcan: 0 passed, 0 failed (could not run; CI=true)"
    exit 1
  fi
  echo "vcan: skipped: $1"
  exit 0
}

native_ok() {
  ip link show "$VCAN" >/dev/null 2>&1 &&
    "$PY" -c "import can; can.Bus(interface='socketcan', channel='$VCAN').shutdown()" \
      >/dev/null 2>&1
}

pins() {  # the host venv's versions of pyproject's dependencies (not textual: no TUI in the
  # VM) and of durand (the independent responder the HIL tests run): read from pyproject.toml,
  # so a dependency added there reaches the VM without a second list to keep
  "$PY" - <<'PYEOF'
import importlib.metadata as m
import re
import tomllib

with open("pyproject.toml", "rb") as f:
    deps = tomllib.load(f)["project"]["dependencies"]
names = [re.match(r"[A-Za-z0-9_.-]+", d).group(0) for d in deps]
names = [n for n in names if n.lower() != "textual"] + ["durand"]
print(" ".join(f"{n}=={m.version(n)}" for n in names))
PYEOF
}

[ -x "$PY" ] || give_up "no Python at $PY (run make venv)"
SHARED_ABS=$(cd "$SHARED" 2>/dev/null && pwd) || give_up "no shared tree at $SHARED (SHARED_DIR)"
if ! make -s -C firmware node SHARED_DIR="$SHARED_ABS" PYTHON=python3 >"$LOG" 2>&1; then
  cat "$LOG"
  give_up "the reference firmware's node did not build (make -C firmware node)"
fi
echo "vcan: reference node built: firmware/build/imu_node"
if native_ok; then
  echo "vcan: running natively on $VCAN"
  CANIMUCAL_VCAN=$VCAN "$PY" "${PYTEST[@]}" 2>&1 | tee "$LOG"
  rc=${PIPESTATUS[0]}
else
  echo "vcan: no usable $VCAN here; running inside the canvm VM ($CANVM)"
  [ -x "$CANVM/setup_vm.sh" ] || give_up "no SocketCAN $VCAN and no VM scripts at $CANVM"
  [ "$(id -u)" = 0 ] || give_up "no SocketCAN $VCAN, and the VM setup needs root"
  PKGS=$(pins) || give_up "cannot read package versions from $PY"
  if ! VM_PIP_PACKAGES="$PKGS" "$CANVM/setup_vm.sh"; then
    give_up "setup_vm.sh failed"
  fi
  VM_TIMEOUT=${VM_TIMEOUT:-1500} "$CANVM/run_in_vm.sh" . \
    "PYTEST_ADDOPTS='${PYTEST_ADDOPTS:-}' PYTHONPATH=. CANIMUCAL_VCAN=$VCAN python ${PYTEST[*]}" \
    2>&1 | tee "$LOG"
  rc=${PIPESTATUS[0]}
fi

count() { grep -oE "[0-9]+ $1" "$LOG" | tail -n 1 | grep -oE '^[0-9]+' || echo 0; }
passed=$(count passed)
failed=$(( $(count failed) + $(count "errors?") ))
skipped=$(count skipped)
echo "vcan: wall time $(( $(date +%s) - t0 )) s"
if [ "$rc" = 0 ] && { [ "$passed" = 0 ] || [ "$skipped" != 0 ]; } && $IS_CI; then
  echo "vcan: $skipped skipped, $passed passed: with CI=true every HIL test must run" >&2
  rc=1
fi
[ "$rc" = 0 ] || [ "$failed" != 0 ] || failed=1   # a crash without a pytest summary
extra=""
[ "$skipped" = 0 ] || extra=", $skipped skipped"
echo "vcan: $passed passed, $failed failed$extra"
exit "$rc"
