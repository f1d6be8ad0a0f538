#!/bin/bash
# Builds MicroPython v1.27.0's bare-metal qemu port (Cortex-M) with the xrce client frozen in through
# this checkout's own manifest.py (unchanged) and the board scripts of tools/mcu/board/.
#   MCU=<work folder> MP_GIT=<a git dir of micropython/micropython> bash tools/mcu/build.sh
# MP_GIT: `git clone --bare https://github.com/micropython/micropython mp.git` once; v1.27.0 is taken
#   from it with `git archive` (no network, no submodules: what needs them is left out below).
#   Or MP_SOURCE=<a v1.27.0 source tree> instead.
# Optional: BOARD (NETDUINO2 | MPS2_AN385, default NETDUINO2), HEAP (bytes of GC heap, default 90112),
#   CPU_HZ (the SysTick clock the port assumes: netduino2 runs at 120 MHz, mps2 at 25 MHz; `port`
#   keeps the port's own 25 MHz), PROJECT (the checkout to freeze, default this one), MSGS (a folder
#   `xrce-client gen-msgs PKG_DIR -o MSGS` wrote: its manifest.py is frozen too, for app_own.py).
# Writes $MCU/fw/<BOARD>-<HEAP>.elf (<BOARD>-<HEAP>-own.elf with MSGS) and prints arm-none-eabi-size.
set -e
W=${MCU:?set MCU to a work folder}
HERE=$(cd "$(dirname "$0")" && pwd)
P=${PROJECT:-$(cd "$HERE/../.." && pwd)}
BOARD=${BOARD:-NETDUINO2}; HEAP=${HEAP:-90112}
if [ -z "$CPU_HZ" ]; then
  case $BOARD in NETDUINO2) CPU_HZ=120000000 ;; *) CPU_HZ=25000000 ;; esac
fi
[ "$CPU_HZ" = port ] && CPU_FLAG= || CPU_FLAG="-DCPU_FREQ_HZ=${CPU_HZ}u"
command -v arm-none-eabi-gcc >/dev/null || { echo "apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm"; exit 1; }
if [ ! -d "$W/mp" ]; then
  if [ -n "$MP_SOURCE" ]; then
    mkdir -p "$W" && cp -r "$MP_SOURCE" "$W/mp"
  else
    : "${MP_GIT:?set MP_GIT to a git dir of micropython/micropython (or MP_SOURCE to a v1.27.0 tree)}"
    mkdir -p "$W/mp" && git --git-dir="$MP_GIT" archive v1.27.0 | tar -x -C "$W/mp"
  fi
fi
[ -x "$W/mp/mpy-cross/build/mpy-cross" ] || nice -n 19 make -C "$W/mp/mpy-cross" -j2 >/dev/null
mkdir -p "$W/fw" "$W/mplib-stub"
# lib/micropython-lib is an empty submodule in the archive; the frozen-manifest rule only checks that
# its README.md exists, and nothing here require()s a micropython-lib package.
echo "stand-in: no micropython-lib packages" > "$W/mplib-stub/README.md"
# The manifest frozen: the board's (the checkout's manifest.py and board/), and your own types'.
# A wrapper rather than a variable in board/manifest.py: an include() of an unset variable fails.
MANIFEST="$HERE/board/manifest.py"
if [ -n "$MSGS" ]; then
  [ -f "$MSGS/manifest.py" ] || { echo "MSGS=$MSGS has no manifest.py (gen-msgs without --mpy writes it)"; exit 1; }
  MANIFEST="$W/fw/manifest-own.py"
  printf 'include("%s")\ninclude("%s")\n' "$HERE/board/manifest.py" "$(cd "$MSGS" && pwd)/manifest.py" > "$MANIFEST"
fi
B=build-$BOARD-$CPU_HZ
FW=$BOARD-$HEAP${MSGS:+-own}   # the firmware with your types beside the one without
# makemanifest skips inputs older than their compiled .mpy: a build from another checkout (or an
# older file) would freeze stale code, so the frozen modules are compiled afresh every time.
rm -rf "$W/mp/ports/qemu/$B/main.o" "$W/mp/ports/qemu/$B/frozen_content.c" "$W/mp/ports/qemu/$B/frozen_mpy"
nice -n 19 make -C "$W/mp/ports/qemu" -j2 BOARD="$BOARD" BUILD="$B" MICROPY_HEAP_SIZE="$HEAP" \
  FROZEN_MANIFEST="$MANIFEST" \
  MICROPY_MANIFEST_XRCE_MANIFEST="$P/manifest.py" MICROPY_MANIFEST_BOARD_SCRIPTS="$HERE/board" \
  MPY_LIB_DIR="$W/mplib-stub" CFLAGS_EXTRA="$CPU_FLAG" > "$W/fw/$FW.log" 2>&1 || {
  tail -30 "$W/fw/$FW.log"; exit 1; }
cp "$W/mp/ports/qemu/$B/firmware.elf" "$W/fw/$FW.elf"
arm-none-eabi-size "$W/fw/$FW.elf"
grep -i "warn\|error\|skip" "$W/fw/$FW.log" | grep -v "^CC\|^MPY\|Werror" | head -20 || true
echo "firmware: $W/fw/$FW.elf"
