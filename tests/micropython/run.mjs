#!/usr/bin/env node
// Runs a script under real MicroPython 1.27 (the WebAssembly port) with the repo's xrce package
// and a synchronous UDP bridge.
//
//   node run.mjs [--heap BYTES] [--stepped] [--mount HOSTDIR:MPDIR ...] [--no-default-mount] script.py [args]
//
// --stepped: the script defines a generator function main(); the harness runs it one next() per
// runPython call. This port cannot collect garbage while Python code runs (the wasm stack holds
// roots it cannot scan), so on an exhausted heap it grows the heap instead of collecting; it
// collects only when a runPython call returns. Stepping gives it that collection point after every
// step, and the heap is then capped for real: the run fails with a MemoryError (exit 1) as soon as
// the heap had to grow past --heap. Before each step /lib/mpheap.py gets the live heap.
//
// Default mount: the repo's xrce/ (.py files only) as /lib/xrce. The .py adapters next to this
// file (e.g. nodeudp_transport.py) are always copied into /lib. Exit status: 0 on success, the
// SystemExit code if the script calls sys.exit, 1 when it raises (traceback on stderr), 2 on a
// usage error, 3 when MicroPython's npm package is not installed next to this file (one line
// saying how to install it).

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";
import { Worker } from "node:worker_threads";
import { DatagramRing } from "./ring.mjs";

const HERE = path.dirname(fileURLToPath(import.meta.url));
const REPO = path.resolve(HERE, "..", "..");
const DEFAULT_HEAP = 256 * 1024;
const REQUEST_TIMEOUT_MS = 5000;
const SKIPPED_DIRS = new Set(["__pycache__", "node_modules"]);
const MICROPYTHON_PACKAGE = "@micropython/micropython-webassembly-pyscript";
const NOT_INSTALLED = 3;

// Imported when a script is to run, not at load: a checkout without `npm ci` gets one line
// that says what to run, where a static import ends in Node's stack trace.
async function importMicroPython() {
  try {
    return (await import(MICROPYTHON_PACKAGE)).loadMicroPython;
  } catch (error) {
    if (error.code !== "ERR_MODULE_NOT_FOUND") throw error;
    const prefix = path.relative(process.cwd(), HERE) || ".";
    process.stderr.write(`run.mjs: MicroPython 1.27 (${MICROPYTHON_PACKAGE}) is not installed: ` +
                         `run \`npm ci --prefix ${prefix} --no-audit --no-fund\` first\n`);
    process.exit(NOT_INSTALLED);
  }
}

function usage(message) {
  process.stderr.write(`run.mjs: ${message}\n`);
  process.stderr.write("usage: node run.mjs [--heap BYTES] [--stepped] [--mount HOSTDIR:MPDIR ...] [--no-default-mount] script.py [args]\n");
  process.exit(2);
}

function parseArgs(argv) {
  const options = { heap: DEFAULT_HEAP, stepped: false, mounts: [], defaultMount: true, script: null, args: [] };
  let i = 0;
  for (; i < argv.length && options.script === null; i++) {
    const arg = argv[i];
    if (arg === "--heap") {
      options.heap = Number.parseInt(argv[++i], 10);
      if (!(options.heap > 0)) usage("--heap needs a positive byte count");
    } else if (arg === "--mount") {
      const spec = argv[++i] || "";
      const colon = spec.lastIndexOf(":");
      if (colon <= 0 || !spec.slice(colon + 1).startsWith("/")) usage(`--mount wants HOSTDIR:/MPDIR, got ${spec}`);
      options.mounts.push({ host: path.resolve(spec.slice(0, colon)), target: spec.slice(colon + 1), pyOnly: false });
    } else if (arg === "--stepped") {
      options.stepped = true;
    } else if (arg === "--no-default-mount") {
      options.defaultMount = false;
    } else if (arg.startsWith("--")) {
      usage(`unknown option ${arg}`);
    } else {
      options.script = arg;
    }
  }
  if (options.script === null) usage("no script given");
  options.args = argv.slice(i);
  if (options.defaultMount && !options.mounts.some((m) => m.target === "/lib/xrce")) {
    options.mounts.unshift({ host: path.join(REPO, "xrce"), target: "/lib/xrce", pyOnly: true });
  }
  return options;
}

function makeDirs(FS, target) {
  let current = "";
  for (const part of target.split("/").filter(Boolean)) {
    current += "/" + part;
    try {
      FS.mkdir(current);
    } catch (error) {
      if (!FS.analyzePath(current).exists) throw error;
    }
  }
}

function copyTree(FS, hostDir, target, pyOnly) {
  if (!fs.statSync(hostDir).isDirectory()) throw new Error(`mount source is not a directory: ${hostDir}`);
  makeDirs(FS, target);
  let copied = 0;
  for (const entry of fs.readdirSync(hostDir, { withFileTypes: true })) {
    const hostPath = path.join(hostDir, entry.name);
    const mpPath = `${target}/${entry.name}`;
    if (entry.isDirectory()) {
      if (!SKIPPED_DIRS.has(entry.name) && !entry.name.startsWith(".")) copied += copyTree(FS, hostPath, mpPath, pyOnly);
    } else if (entry.isFile() && (!pyOnly || entry.name.endsWith(".py"))) {
      FS.writeFile(mpPath, fs.readFileSync(hostPath));
      copied += 1;
    }
  }
  return copied;
}

// Output goes through fs.writeSync: the main thread may be blocked in Atomics.wait for a long time
// and asynchronous stream writes would sit in the event loop until it returns.
function byteSink(fd) {
  const pending = [];
  return {
    put(bytes) {
      for (const b of bytes) {
        pending.push(b);
        if (b === 10) this.flush();
      }
    },
    flush() {
      if (pending.length) fs.writeSync(fd, Uint8Array.from(pending));
      pending.length = 0;
    },
  };
}

// Synchronous request/response with the UDP worker over a shared block:
// int32 [0] = id of the request answered last, [1] = value, [2] = error text length, bytes 16.. = error text.
class Reply {
  static allocate() {
    return new SharedArrayBuffer(16 + 1024);
  }

  constructor(worker, buffer) {
    this.worker = worker;
    this.ints = new Int32Array(buffer, 0, 4);
    this.text = new Uint8Array(buffer, 16);
    this.nextId = 1;
  }

  request(op, fields, transfer) {
    const id = this.nextId++;
    this.worker.postMessage({ op, id, ...fields }, transfer || []);
    const deadline = performance.now() + REQUEST_TIMEOUT_MS;
    for (;;) {
      const answered = Atomics.load(this.ints, 0);
      if (answered === id) break;
      const left = deadline - performance.now();
      if (left <= 0) throw new Error(`${op} got no answer from the UDP worker within ${REQUEST_TIMEOUT_MS} ms`);
      Atomics.wait(this.ints, 0, answered, left);
    }
    const errorLength = Atomics.load(this.ints, 2);
    if (errorLength) throw new Error(`${op}: ${new TextDecoder().decode(this.text.slice(0, errorLength))}`);
    return Atomics.load(this.ints, 1);
  }
}

async function startWorker() {
  const replyBuffer = Reply.allocate();
  const worker = new Worker(new URL("./udp_worker.mjs", import.meta.url), { workerData: { replyBuffer } });
  await new Promise((resolve, reject) => {
    worker.once("message", resolve);
    worker.once("error", reject);
  });
  return new Reply(worker, replyBuffer);
}

// Bytes across the JS<->MicroPython boundary (checked on 1.27.0, see README.md): a Python
// bytes/bytearray/memoryview reaches JS as an opaque PyProxy and a Uint8Array reaches Python as a
// JsProxy (bytes(proxy) works but costs one boundary crossing per byte). binascii's C code
// converts both ways at memory speed through a hex str, which does cross natively.
function makeBytesBridge(mp) {
  const binascii = mp.pyimport("binascii");
  return {
    toUint8Array(value) {
      if (ArrayBuffer.isView(value)) return new Uint8Array(value.buffer, value.byteOffset, value.byteLength);
      if (value instanceof mp.PyProxy) return Buffer.from(binascii.hexlify(value).decode(), "hex");
      throw new TypeError("expected bytes, bytearray or memoryview");
    },
    toPythonBytes(bytes) {
      return binascii.unhexlify(Buffer.from(bytes.buffer, bytes.byteOffset, bytes.byteLength).toString("hex"));
    },
  };
}

// A JS exception thrown inside a function that MicroPython called is not turned into a Python
// exception: it unwinds through the wasm frames and out of runPython, killing the script. So every
// nodeudp function catches, remembers the message for last_error() and returns -1.
function makeNodeUdp(reply, bytesBridge, memory) {
  const rings = new Map();
  const unread = new Map(); // handle -> the tail of a datagram recv_into left for the next read (stream mode)
  let nextHandle = 1;
  let lastError = "";
  const ringOf = (handle) => {
    const ring = rings.get(handle);
    if (!ring) throw new Error(`no open socket with handle ${handle}`);
    return ring;
  };
  const guarded = (fn) => (...args) => {
    try {
      return fn(...args);
    } catch (error) {
      lastError = String(error.message || error);
      return -1;
    }
  };
  return {
    open: guarded((host, port) => {
      if (typeof host !== "string" || !Number.isInteger(port)) throw new TypeError("open(host: str, port: int)");
      const handle = nextHandle++;
      const buffer = DatagramRing.allocate();
      reply.request("open", { handle, host, port, ring: buffer });
      rings.set(handle, new DatagramRing(buffer));
      return handle;
    }),
    // A TCP connection read the same way as a stream-mode socket (recv_into with stream=true);
    // the end of the stream reads as a 0-byte datagram.
    open_tcp: guarded((host, port) => {
      if (typeof host !== "string" || !Number.isInteger(port)) {
        throw new TypeError("open_tcp(host: str, port: int)");
      }
      const handle = nextHandle++;
      const buffer = DatagramRing.allocate();
      reply.request("openTcp", { handle, host, port, ring: buffer });
      rings.set(handle, new DatagramRing(buffer));
      return handle;
    }),
    send: guarded((handle, data) => {
      ringOf(handle);
      // Copied so that the worker owns a stable buffer (a view may alias the wasm heap).
      const payload = new Uint8Array(bytesBridge.toUint8Array(data));
      return reply.request("send", { handle, payload }, [payload.buffer]);
    }),
    recv: guarded((handle, timeoutMs) => {
      const ring = ringOf(handle);
      const wait = timeoutMs === null || timeoutMs === undefined ? Infinity : Math.max(0, timeoutMs);
      const datagram = ring.shiftWaiting(wait);
      return datagram === null ? null : bytesBridge.toPythonBytes(datagram);
    }),
    // The same with the bytes as a hex str, which crosses without a PyProxy: a proxied Python
    // object stays referenced from the MicroPython heap until a JS collection finalizes the proxy,
    // so a long run over send/recv would look like a leak (nodeudp_transport.py uses these).
    send_hex: guarded((handle, hex) => {
      ringOf(handle);
      if (typeof hex !== "string") throw new TypeError("send_hex(handle, hex: str)");
      const payload = new Uint8Array(Buffer.from(hex, "hex"));
      return reply.request("send", { handle, payload }, [payload.buffer]);
    }),
    recv_hex: guarded((handle, timeoutMs) => {
      const ring = ringOf(handle);
      const wait = timeoutMs === null || timeoutMs === undefined ? Infinity : Math.max(0, timeoutMs);
      const datagram = ring.shiftWaiting(wait);
      return datagram === null ? null : Buffer.from(datagram.buffer, datagram.byteOffset, datagram.byteLength).toString("hex");
    }),
    // The same again without any Python object in between: the bytes are read from, or written
    // into, the MicroPython heap at the address uctypes.addressof gave (the GC never moves an
    // object, and the call is synchronous). A send or receive then allocates nothing on the
    // MicroPython heap, as a board's socket does not; the hex strs above cost ~4 bytes of
    // garbage per byte moved, which a capped run would otherwise count against the firmware.
    send_at: guarded((handle, address, length) => {
      ringOf(handle);
      if (!Number.isInteger(address) || !Number.isInteger(length) || length < 0) {
        throw new TypeError("send_at(handle, address: int, length: int)");
      }
      const payload = new Uint8Array(length);
      for (let i = 0; i < length; i++) payload[i] = memory.getValue(address + i, "i8");
      return reply.request("send", { handle, payload }, [payload.buffer]);
    }),
    // Copies at most `size` bytes of the next datagram to `address`; returns the count, or None on
    // timeout. `stream`: keep what did not fit for the next call (a byte stream); otherwise it is
    // dropped, as recvfrom drops the tail of a datagram longer than its buffer.
    recv_into: guarded((handle, address, size, timeoutMs, stream) => {
      const ring = ringOf(handle);
      if (!Number.isInteger(address) || !Number.isInteger(size) || size < 0) {
        throw new TypeError("recv_into(handle, address: int, size: int, timeout_ms, stream: bool)");
      }
      let datagram = unread.get(handle);
      unread.delete(handle);
      if (datagram === undefined) {
        const wait = timeoutMs === null || timeoutMs === undefined ? Infinity : Math.max(0, timeoutMs);
        datagram = ring.shiftWaiting(wait);
        if (datagram === null) return null;
      }
      const count = Math.min(size, datagram.byteLength);
      for (let i = 0; i < count; i++) memory.setValue(address + i, datagram[i], "i8");
      if (stream && count < datagram.byteLength) unread.set(handle, datagram.slice(count));
      return count;
    }),
    // 1 once something can be read (a datagram, or the tail a stream read left), else 0 after
    // timeout_ms; takes nothing. The harness socket's poll ioctl waits with it.
    readable: guarded((handle, timeoutMs) => {
      const ring = ringOf(handle);
      if (unread.has(handle)) return 1;
      return ring.waitReadable(Math.max(0, timeoutMs || 0)) ? 1 : 0;
    }),
    close: guarded((handle) => {
      unread.delete(handle);
      if (!rings.delete(handle)) return 0;
      reply.request("close", { handle });
      return 1;
    }),
    local_port: guarded((handle) => {
      ringOf(handle);
      return reply.request("localPort", { handle });
    }),
    dropped: guarded((handle) => ringOf(handle).stats().dropped),
    last_error: () => lastError,
  };
}

function pythonStr(text) {
  // JSON string literals are valid Python string literals for everything JSON.stringify emits.
  return JSON.stringify(text);
}

const RUN_SCRIPT = (scriptPath, argv, stepped) => `
import sys
if "/lib" not in sys.path:
    sys.path.append("/lib")
sys.path[0] = "/app"
sys.argv.clear()
for _arg in [${argv.map(pythonStr).join(", ")}]:
    sys.argv.append(_arg)
del _arg

import gc
# gc.mem_free() counts the heap the port may still add ("max new split"), a constant: the sum only
# changes when the heap grows.
_heap_sum = gc.mem_alloc() + gc.mem_free()
_steps = None

def _exit_code(stop):
    status = stop.args[0] if stop.args else None
    if status is None:
        return 0
    if isinstance(status, int):
        return status
    print(status, file=sys.stderr)
    return 1

def _run_main(path):
    global _steps
    try:
        with open(path) as source:
            code = compile(source.read(), path, "exec")
        namespace = {"__name__": "__main__", "__file__": path}
        exec(code, namespace)
        if ${stepped ? "True" : "False"}:
            _steps = namespace["main"]()
        return 0
    except SystemExit as stop:
        return _exit_code(stop)
    except BaseException as error:
        sys.print_exception(error, sys.stderr)
        return 1

def _step():
    # Called by run.mjs once per step: None while the generator has more to do, else the exit status.
    global _steps
    if _steps is None:
        return 0
    grown = gc.mem_alloc() + gc.mem_free() - _heap_sum
    if grown > 0:
        _steps = None
        print("MemoryError: the heap had to grow by %d bytes past its --heap cap" % grown, file=sys.stderr)

        return 1
    import mpheap
    mpheap.live = gc.mem_alloc()
    mpheap.steps += 1
    try:
        next(_steps)
    except StopIteration:
        _steps = None
        return 0
    except SystemExit as stop:
        _steps = None
        return _exit_code(stop)
    except BaseException as error:
        _steps = None
        sys.print_exception(error, sys.stderr)
        return 1
    # Nothing was collected during the step: what is allocated now is its high-water mark.
    high = gc.mem_alloc()
    mpheap.high = high
    if high > mpheap.peak:
        mpheap.peak = high
    gc.collect()  # in this port: asks for a collection when this runPython call returns
    return None

_exit_status = _run_main(${pythonStr(scriptPath)})
`;

async function main() {
  const options = parseArgs(process.argv.slice(2));
  if (!fs.existsSync(options.script)) usage(`script not found: ${options.script}`);
  const loadMicroPython = await importMicroPython();
  const stdout = byteSink(1);
  const stderr = byteSink(2);
  const mp = await loadMicroPython({
    heapsize: options.heap,
    linebuffer: false,
    stdout: (bytes) => stdout.put(bytes),
    stderr: (bytes) => stderr.put(bytes),
  });
  for (const mount of options.mounts) copyTree(mp.FS, mount.host, mount.target, mount.pyOnly);
  makeDirs(mp.FS, "/lib");
  for (const name of fs.readdirSync(HERE)) {
    // A mount may bring an adapter compiled to .mpy (a board would run it so): MicroPython looks
    // for the .py first, so the source copy is left out.
    if (name.endsWith(".py") && !mp.FS.analyzePath(`/lib/${name.slice(0, -3)}.mpy`).exists) {
      mp.FS.writeFile(`/lib/${name}`, fs.readFileSync(path.join(HERE, name)));
    }
  }
  makeDirs(mp.FS, "/app");
  const scriptPath = `/app/${path.basename(options.script)}`;
  mp.FS.writeFile(scriptPath, fs.readFileSync(options.script));

  const reply = await startWorker();
  mp.registerJsModule("nodeudp", makeNodeUdp(reply, makeBytesBridge(mp), mp._module));
  let status;
  try {
    mp.runPython(RUN_SCRIPT(scriptPath, [scriptPath, ...options.args], options.stepped));
    status = mp.globals.get("_exit_status");
    if (options.stepped && status === 0) {
      // Only ints and None cross here: a Python object handed to JS (a PyProxy) would stay
      // referenced from the MicroPython heap until JS finalizes the proxy.
      for (;;) {
        mp.runPython("_exit_status = _step()");
        const stepStatus = mp.globals.get("_exit_status");
        if (stepStatus !== null && stepStatus !== undefined) {
          status = stepStatus;
          break;
        }
      }
    }
  } catch (error) {
    // Only a failure of the harness prelude itself lands here; script errors are caught in Python.
    stderr.put(new TextEncoder().encode(`run.mjs: ${error.stack || error}\n`));
    status = 1;
  }
  stdout.flush();
  stderr.flush();
  // A loaded CI machine once saw terminate() not settle for 60 s after a script had finished;
  // process.exit ends the worker as well, so the wait for it is bounded.
  await Promise.race([reply.worker.terminate(), new Promise((resolve) => setTimeout(resolve, 2000).unref())]);
  process.exit(typeof status === "number" ? status : 1);
}

await main();
