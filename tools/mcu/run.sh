#!/bin/bash
# One run in a private network namespace (loopback only): qemu + xrce-agent serial + rclpy checker + a
# command typed at the board's REPL.  See drive.py for the arguments, e.g.
#   MCU=<work folder> bash tools/mcu/run.sh <run name> --fw "$MCU/fw/NETDUINO2-90112.elf" \
#       --check tb3 --board-cmd "import app_tb3; app_tb3.main(57, 60)"
# Logs go to $MCU/runs/<run name>/. XRCE_VENV: the venv with xrce and rclpy (default: the checkout's .venv).
set -e
W=${MCU:?set MCU to a work folder}
HERE=$(cd "$(dirname "$0")" && pwd)
V=${XRCE_VENV:-$(cd "$HERE/../.." && pwd)/.venv}
NAME=${1:?run name}; shift
mkdir -p "$W/runs/$NAME"
exec unshare -n bash -c 'ip link set lo up; exec nice -n 10 "$0" "$@"' \
  "$V/bin/python" "$HERE/drive.py" --workdir "$W/runs/$NAME" "$@"
