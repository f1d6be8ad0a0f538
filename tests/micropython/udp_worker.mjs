// Owns the UDP sockets for run.mjs. It runs on its own thread so that datagrams keep arriving
// (and sends keep completing) while the main thread is blocked inside synchronous MicroPython code.
//
// Requests arrive by postMessage; each is answered through the shared reply block (see run.mjs:
// Reply) so the blocked main thread can Atomics.wait for it. Received datagrams go into the
// handle's DatagramRing.

import dgram from "node:dgram";
import net from "node:net";
import { parentPort, workerData } from "node:worker_threads";
import { DatagramRing } from "./ring.mjs";

const reply = new Int32Array(workerData.replyBuffer, 0, 4);
const replyText = new Uint8Array(workerData.replyBuffer, 16);
const encoder = new TextEncoder();
const sockets = new Map();

function answer(requestId, value, error) {
  let errorLength = 0;
  if (error) {
    const encoded = encoder.encode(String(error.message || error)).subarray(0, replyText.length);
    replyText.set(encoded);
    errorLength = encoded.length;
  }
  Atomics.store(reply, 1, value | 0);
  Atomics.store(reply, 2, errorLength);
  Atomics.store(reply, 0, requestId);
  Atomics.notify(reply, 0);
}

function open({ id, handle, host, port, ring }) {
  const socket = dgram.createSocket(net.isIPv6(host) ? "udp6" : "udp4");
  const datagrams = new DatagramRing(ring);
  let settled = false;
  const fail = (error) => {
    if (settled) return;
    settled = true;
    socket.close();
    answer(id, 0, error);
  };
  socket.on("message", (message) => datagrams.push(message));
  socket.on("error", (error) => {
    // Before connect() completes an error means the open failed. Afterwards the likely cause is
    // ICMP port-unreachable for an earlier send (no agent listening yet): a real UDP client
    // ignores that and retries, so only the open request reports errors.
    fail(error);
  });
  socket.bind(0, () => {
    try {
      socket.connect(port, host, (error) => {
        if (error) return fail(error);
        if (settled) return;
        settled = true;
        sockets.set(handle, socket);
        answer(id, handle);
      });
    } catch (error) {
      fail(error); // bad port or address: thrown synchronously, not passed to the callback
    }
  });
}

// A TCP connection for the harness' SOCK_STREAM sockets: its bytes go into the ring as they come
// (run.mjs reads them as one stream), and the end of the stream as an empty datagram.
function openTcp({ id, handle, host, port, ring }) {
  const datagrams = new DatagramRing(ring);
  let settled = false;
  const socket = net.connect({ host, port });
  socket.setNoDelay(true);
  socket.on("connect", () => {
    settled = true;
    sockets.set(handle, socket);
    answer(id, handle);
  });
  socket.on("data", (chunk) => datagrams.push(chunk));
  socket.on("end", () => datagrams.push(new Uint8Array(0)));
  socket.on("error", (error) => {
    if (!settled) {
      settled = true;
      answer(id, 0, error);
    }
  });
}

function send({ id, handle, payload }) {
  const socket = sockets.get(handle);
  if (!socket) return answer(id, 0, new Error(`no open socket with handle ${handle}`));
  if (socket instanceof net.Socket) {
    socket.write(payload, (error) => answer(id, error ? 0 : payload.length, error));
    return;
  }
  socket.send(payload, (error) => answer(id, error ? 0 : payload.length, error));
}

function close({ id, handle }) {
  const socket = sockets.get(handle);
  if (!socket) return answer(id, 0);
  sockets.delete(handle);
  if (socket instanceof net.Socket) {
    socket.destroy();
    answer(id, 1);
    return;
  }
  socket.close(() => answer(id, 1));
}

function localPort({ id, handle }) {
  const socket = sockets.get(handle);
  if (!socket) return answer(id, 0, new Error(`no open socket with handle ${handle}`));
  answer(id, socket.address().port);
}

const operations = { open, openTcp, send, close, localPort };

parentPort.on("message", (request) => {
  try {
    operations[request.op](request);
  } catch (error) {
    answer(request.id, 0, error);
  }
});
parentPort.postMessage("ready");
