#!/usr/bin/env bash
# Installs qemu-system-arm (Debian's package) where it is missing and this runs as root with
# apt-get; does nothing where it is present. Never fails: whether QEMU is there afterwards is
# what firmware/m4-emu/ci.sh checks (and says SKIPPED, never passed, where it is not).
# .ci/run starts it at CI's start, beside the first builds; ci.sh runs it again (then a no-op).
if ! command -v qemu-system-arm >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    echo "installing qemu-system-arm (Debian package)"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq qemu-system-arm; } >/dev/null 2>&1 || true
  fi
fi
exit 0
