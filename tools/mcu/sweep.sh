#!/bin/bash
# Smallest heap for the TurtleBot3 firmware (workload b): for each heap size, rebuild and run it for
# SECONDS (default 60) over the UART link, with the ROS checker; prints one line per heap.
#   MCU=<work folder> MP_GIT=<git dir> bash tools/mcu/sweep.sh 65536 49152 40960 ...
# Optional: BOARD (NETDUINO2), KIND (custom | serial), RUN_S (60; not SECONDS, which bash sets), and
# build.sh's and run.sh's variables.
W=${MCU:?}
HERE=$(cd "$(dirname "$0")" && pwd)
BOARD=${BOARD:-NETDUINO2}; KIND=${KIND:-custom}; SECONDS_RUN=${RUN_S:-60}
MACHINE=netduino2; [ "$BOARD" = MPS2_AN385 ] && MACHINE=mps2-an385
for HEAP in "$@"; do
  BOARD=$BOARD HEAP=$HEAP bash "$HERE/build.sh" > "$W/fw/build-$BOARD-$HEAP.out" 2>&1 || { echo "heap $HEAP: build failed"; continue; }
  NAME=sweep-$BOARD-$KIND-$HEAP
  bash "$HERE/run.sh" "$NAME" --fw "$W/fw/$BOARD-$HEAP.elf" --machine "$MACHINE" --check tb3 --seconds "$SECONDS_RUN" \
    --timeout $((SECONDS_RUN + 60)) --board-cmd "import app_tb3; app_tb3.main(57, $SECONDS_RUN, \"$KIND\", 10000)" \
    > "$W/runs/$NAME.out" 2>&1
  L="$W/runs/$NAME/board.log"
  if grep -q "^\[.*\] DONE" "$L"; then verdict=PASS; else verdict=FAIL; fi
  echo "heap $HEAP ($KIND): $verdict; $(grep -o 'HEAP setup.*' "$L" | head -1); $(grep -o 'HEAP after_run.*' "$L" | head -1);" \
    "$(grep -o 'published {.*' "$L" | head -1); $(grep -o 'max free sz: [0-9]*' "$L" | tail -1);" \
    "error: $(grep -E 'Error|MEMORYERROR' "$L" | grep -v Traceback | head -2 | tr '\n' ' ')"
done
