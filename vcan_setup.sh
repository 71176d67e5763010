#!/bin/sh
# vcan_setup.sh [NAME] - load the vcan kernel module, create the virtual CAN interface NAME
# (default vcan0) and bring it up. Idempotent: an existing interface is only brought up.
# Needs root (sudo ./vcan_setup.sh) and a Linux kernel built with CONFIG_CAN_VCAN.
set -eu
NAME=${1:-vcan0}

fail() { echo "vcan_setup: $*" >&2; exit 1; }

case "$NAME" in
  ''|*[!A-Za-z0-9_.-]*) fail "bad interface name '$NAME'";;
esac
[ "$(uname -s)" = Linux ] || fail "SocketCAN needs Linux (this is $(uname -s))"
command -v ip >/dev/null 2>&1 || fail "the 'ip' command is missing: apt-get install iproute2"

if ip link show "$NAME" >/dev/null 2>&1; then
  if ip link show "$NAME" | grep -q 'state UP\|,UP'; then
    echo "vcan_setup: $NAME is already up"
    exit 0
  fi
  [ "$(id -u)" = 0 ] || fail "$NAME exists but is down; bringing it up needs root: sudo $0 $NAME"
  ip link set "$NAME" up || fail "cannot bring $NAME up"
  echo "vcan_setup: $NAME is up"
  exit 0
fi

[ "$(id -u)" = 0 ] || fail "creating $NAME needs root: sudo $0 $*"

if ! grep -qw vcan /proc/modules 2>/dev/null && [ ! -d /sys/module/vcan ]; then
  if ! modprobe vcan 2>/dev/null; then
    fail "this kernel ($(uname -r)) has no vcan module (modprobe vcan failed). \
Install your distribution's full kernel modules (e.g. linux-modules-extra-$(uname -r)), \
or use a VM: ../shared/tools/canvm (see docs/hil.md)"
  fi
fi
if ! ip link add dev "$NAME" type vcan 2>/dev/null; then
  fail "cannot create $NAME: the kernel refused 'ip link add dev $NAME type vcan' \
(no vcan support in this kernel or container?)"
fi
ip link set "$NAME" up || fail "cannot bring $NAME up"
echo "vcan_setup: $NAME created and up"
