#!/usr/bin/env bash
# Flash and static RAM of a Cortex-M ELF, from its section headers, for the firmware checks
# (`firmware/ci.sh`, `firmware/m4-emu/ci.sh`): sourced, `elf_size FILE` sets FLASH and RAM (bytes).
#
# Flash = .vector_table + .text + .rodata + .data (initial values of .data live in flash);
# RAM   = .data + .bss + .uninit (static; the stack grows into the rest).
elf_size() {
  local elf="$1" name size bytes
  FLASH=0; RAM=0
  # readelf -S -W: "[Nr] Name Type Address Off Size ..."; the size is the 4th field after the name.
  while read -r name size; do
    bytes=$((16#$size))
    case "$name" in
      .vector_table|.text|.rodata) FLASH=$((FLASH + bytes)) ;;
      .data) FLASH=$((FLASH + bytes)); RAM=$((RAM + bytes)) ;;
      .bss|.uninit) RAM=$((RAM + bytes)) ;;
    esac
  done < <(readelf -S -W "$elf" | sed -n 's/^ *\[ *[0-9]*\] *//p' | awk '{ print $1, $5 }')
}
