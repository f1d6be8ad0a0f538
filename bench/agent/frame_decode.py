"""CPython throughput of the serial frame decoder (FrameDecoder.feed, as the agent's serial links and
the CPython client use it), this checkout beside a baseline revision, interleaved in one run.

    python bench/agent/frame_decode.py [--base REV] [--runs 9] [--megabytes 1]

The stream is ``--megabytes`` of frames as a serial link carries them: payloads of 12 (heartbeats,
ACKNACKs), 64 and 200 bytes (samples) and a few of 1024, random bytes (so about one byte in 128 is
escaped), fed in 65536-byte chunks (the agent's read size) and in 4095-byte chunks (a pty's usual
read). The baseline's framing.py is read from git (``git show REV:xrce/transports/framing.py``) and
loaded as its own module beside this checkout's; both use this checkout's CRC functions. Figures are
medians over ``--runs`` alternating runs of CPU time (process_time: a loaded machine's waits
do not count), and the median of the ratios of each pair of runs.
"""

import argparse
import random
import statistics
import subprocess
import sys
import time
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from xrce.transports import framing  # noqa: E402


def load_baseline(rev):
    source = subprocess.run(["git", "show", "%s:xrce/transports/framing.py" % rev], cwd=ROOT,
                            check=True, capture_output=True, text=True).stdout
    module = types.ModuleType("framing_%s" % rev)
    exec(compile(source, "%s:xrce/transports/framing.py" % rev, "exec"), module.__dict__)
    return module


def make_stream(megabytes, seed=1):
    rng = random.Random(seed)
    sizes = (12, 12, 64, 200, 200, 200, 1024)
    parts, total, frames = [], 0, 0
    while total < megabytes * 1_000_000:
        payload = rng.randbytes(rng.choice(sizes))
        frame = framing.encode_frame(payload, 0, 1)
        parts.append(frame)
        total += len(frame)
        frames += 1
    return b"".join(parts), frames


def run_once(module, data, chunk, expected_frames):
    decoder = module.FrameDecoder(local_addr=1)
    got = 0
    start = time.process_time()
    for offset in range(0, len(data), chunk):
        got += len(decoder.feed(data[offset : offset + chunk]))
    elapsed = time.process_time() - start
    if got != expected_frames or decoder.dropped_bytes:
        raise SystemExit("%s decoded %d of %d frames" % (module.__name__, got, expected_frames))
    return elapsed


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", default="main", help="baseline revision (default: main)")
    parser.add_argument("--runs", type=int, default=21)
    parser.add_argument("--megabytes", type=float, default=1.0)
    args = parser.parse_args(argv)
    baseline = load_baseline(args.base)
    data, frames = make_stream(args.megabytes)
    print("stream: %d bytes, %d frames; medians of %d runs" % (len(data), frames, args.runs))
    for chunk in (65536, 4095):
        times = {"baseline": [], "this": []}
        for _ in range(args.runs):
            times["baseline"].append(run_once(baseline, data, chunk, frames))
            times["this"].append(run_once(framing, data, chunk, frames))
        base = statistics.median(times["baseline"])
        this = statistics.median(times["this"])
        # Each run of this beside the baseline run just before it: load drifts less within a pair.
        ratio = statistics.median(b / t for b, t in zip(times["baseline"], times["this"]))
        print("chunk %5d: baseline %s %6.2f MB/s %7.0f frames/s | this %6.2f MB/s %7.0f frames/s | "
              "throughput %+.1f %% (median of pairs)"
              % (chunk, args.base, len(data) / base / 1e6, frames / base, len(data) / this / 1e6,
                 frames / this, (ratio - 1) * 100))


if __name__ == "__main__":
    sys.exit(main())
