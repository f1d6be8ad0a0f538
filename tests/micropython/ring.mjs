// Single-producer/single-consumer ring of datagrams in a SharedArrayBuffer.
//
// The UDP worker thread writes, the MicroPython (main) thread reads. Python's recv() must block
// synchronously, and the main thread's event loop is frozen while MicroPython runs, so the worker
// cannot deliver datagrams by postMessage; it appends them here and wakes the reader with
// Atomics.notify on SEQ.
//
// Records are [int32 length][payload padded to 4 bytes]. A record that would cross the end of the
// data area is written at offset 0 instead, after a WRAP marker. WRITE == READ means empty, so the
// writer always leaves at least 4 bytes free.

const WRITE = 0; // byte offset of the next record, owned by the writer
const READ = 1; // byte offset of the next unread record, owned by the reader
const SEQ = 2; // bumped on every record written: the futex the reader waits on
const DROPPED = 3; // datagrams discarded because the ring was full (like a full socket buffer)
const RECEIVED = 4;
const HEADER_INTS = 8;
const HEADER_BYTES = HEADER_INTS * 4;
const WRAP = -1;

export const DEFAULT_RING_BYTES = 1 << 20;

function padded(length) {
  return (length + 3) & ~3;
}

export class DatagramRing {
  static allocate(capacity = DEFAULT_RING_BYTES) {
    if (capacity % 4 !== 0 || capacity < 64) throw new RangeError("ring capacity must be a multiple of 4, >= 64");
    return new SharedArrayBuffer(HEADER_BYTES + capacity);
  }

  constructor(sab) {
    this.header = new Int32Array(sab, 0, HEADER_INTS);
    this.capacity = sab.byteLength - HEADER_BYTES;
    this.data = new Uint8Array(sab, HEADER_BYTES, this.capacity);
    this.view = new DataView(sab, HEADER_BYTES, this.capacity);
  }

  // Writer side (worker). Returns false when the datagram had to be dropped.
  push(bytes) {
    const need = 4 + padded(bytes.length);
    let write = Atomics.load(this.header, WRITE);
    const read = Atomics.load(this.header, READ);
    let at = -1;
    if (read > write) {
      if (write + need < read) at = write;
    } else if (write + need < this.capacity || (write + need === this.capacity && read !== 0)) {
      at = write;
    } else if (need < read) {
      this.view.setInt32(write, WRAP, true);
      at = 0;
    }
    if (at < 0) {
      Atomics.add(this.header, DROPPED, 1);
      return false;
    }
    this.view.setInt32(at, bytes.length, true);
    this.data.set(bytes, at + 4);
    write = (at + need) % this.capacity;
    Atomics.store(this.header, WRITE, write);
    Atomics.add(this.header, RECEIVED, 1);
    Atomics.add(this.header, SEQ, 1);
    Atomics.notify(this.header, SEQ);
    return true;
  }

  // Reader side (main thread). Returns a copy of the oldest datagram, or null when empty.
  shift() {
    let read = Atomics.load(this.header, READ);
    const write = Atomics.load(this.header, WRITE);
    if (read === write) return null;
    let length = this.view.getInt32(read, true);
    if (length === WRAP) {
      read = 0;
      length = this.view.getInt32(0, true);
    }
    const datagram = this.data.slice(read + 4, read + 4 + length);
    Atomics.store(this.header, READ, (read + 4 + padded(length)) % this.capacity);
    return datagram;
  }

  // Blocks the calling thread until a datagram is available or timeoutMs elapses.
  shiftWaiting(timeoutMs) {
    const deadline = performance.now() + timeoutMs;
    for (;;) {
      const seq = Atomics.load(this.header, SEQ);
      const datagram = this.shift();
      if (datagram !== null) return datagram;
      const left = deadline - performance.now();
      if (left <= 0) return null;
      Atomics.wait(this.header, SEQ, seq, left);
    }
  }

  // Blocks until a datagram is there (true) or timeoutMs elapses (false), taking nothing.
  waitReadable(timeoutMs) {
    const deadline = performance.now() + timeoutMs;
    for (;;) {
      const seq = Atomics.load(this.header, SEQ);
      if (Atomics.load(this.header, READ) !== Atomics.load(this.header, WRITE)) return true;
      const left = deadline - performance.now();
      if (left <= 0) return false;
      Atomics.wait(this.header, SEQ, seq, left);
    }
  }

  stats() {
    return { received: Atomics.load(this.header, RECEIVED), dropped: Atomics.load(this.header, DROPPED) };
  }
}
