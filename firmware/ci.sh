#!/usr/bin/env bash
# Firmware CI: builds the no_std crates for the probe's target (nothing from std can sneak in),
# builds the nRF52840 board binary in release, and reports its flash and RAM from the ELF.
# Nothing is flashed (no probe-rs, no board here).
#
# Flash = .vector_table + .text + .rodata + .data (initial values live in flash);
# RAM   = .data + .bss + .uninit (static; the stack grows into the rest of the 256 KiB).
# Targets: flash <= 64 KiB, RAM <= 16 KiB.
set -euo pipefail
cd "$(dirname "$0")/.."
TARGET=thumbv7em-none-eabihf
rustup target add "$TARGET" >/dev/null 2>&1 || rustup target list --installed | grep -q "$TARGET"

export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$PWD/target}"
cargo build --release -p palpate-protocol -p palpate-runtime -p palpate-probe --target "$TARGET"

(cd firmware/nrf52840 && CARGO_TARGET_DIR="$CARGO_TARGET_DIR/nrf52840" cargo build --release)
ELF="$CARGO_TARGET_DIR/nrf52840/$TARGET/release/palpate-probe-nrf52840"

source firmware/elf-size.sh
elf_size "$ELF"
readelf -S -W "$ELF" | grep -E '\.(vector_table|text|rodata|data|bss|uninit) '
echo "nrf52840 firmware: flash ${FLASH} bytes ($(( (FLASH + 1023) / 1024 )) KiB), static RAM ${RAM} bytes ($(( (RAM + 1023) / 1024 )) KiB)"
status=0
if (( FLASH > 64 * 1024 )); then echo "flash ${FLASH} B exceeds the 64 KiB budget"; status=1; fi
if (( RAM > 16 * 1024 )); then echo "RAM ${RAM} B exceeds the 16 KiB budget"; status=1; fi
echo "{\"firmware\":\"nrf52840\",\"flash_bytes\":${FLASH},\"ram_bytes\":${RAM}}"
exit $status
