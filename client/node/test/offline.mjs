// The offline CLI's answers, for comparing the client's with: running
// geodesicd's subcommands, and reading their .f64, .npy and .npz files.
import { execFileSync } from "node:child_process";
import { readFileSync } from "node:fs";
import { join } from "node:path";

/** Runs `BIN/geodesicd ARGS...` (at most 60 s); its stdout. */
export function geodesicd(bin, args) {
  return execFileSync(join(bin, "geodesicd"), args, {
    encoding: "utf8", timeout: 60000, stdio: ["ignore", "pipe", "pipe"],
  });
}

/** A copy of bytes in an aligned ArrayBuffer, as a typed array of `Type`. */
function aligned(bytes, Type) {
  const copy = new Uint8Array(bytes.length);
  copy.set(bytes);
  return new Type(copy.buffer, 0, bytes.length / Type.BYTES_PER_ELEMENT);
}

export function readF64(path) {
  return aligned(readFileSync(path), Float64Array);
}

const TYPES = { "<f8": Float64Array, "<f4": Float32Array, "<u4": Uint32Array, "<i4": Int32Array,
  "<i8": BigInt64Array, "<u8": BigUint64Array };

/** An .npy's { shape, data } (data a typed array of its dtype). */
export function parseNpy(bytes) {
  if (bytes.subarray(1, 6).toString("latin1") !== "NUMPY") throw new Error("not an .npy");
  const major = bytes[6];
  const headerLength = major === 1 ? bytes.readUInt16LE(8) : bytes.readUInt32LE(8);
  const start = major === 1 ? 10 : 12;
  const header = bytes.subarray(start, start + headerLength).toString("latin1");
  const descr = /'descr':\s*'([^']+)'/.exec(header)[1];
  const shape = /'shape':\s*\(([^)]*)\)/.exec(header)[1].split(",").filter((s) => s.trim())
    .map(Number);
  const Type = TYPES[descr];
  // Other dtypes (an .npz's format string) are kept as bytes.
  const data = bytes.subarray(start + headerLength);
  return { shape, descr, data: Type ? aligned(data, Type) : Buffer.from(data) };
}

export function readNpy(path) {
  return parseNpy(readFileSync(path));
}

/** The members of an .npz (a zip the CLI writes uncompressed) by name, each parsed. */
export function readNpz(path) {
  const zip = readFileSync(path);
  const out = {};
  let at = 0;
  while (at + 30 <= zip.length && zip.readUInt32LE(at) === 0x04034b50) {
    const method = zip.readUInt16LE(at + 8);
    const size = zip.readUInt32LE(at + 18);
    const nameLength = zip.readUInt16LE(at + 26);
    const extraLength = zip.readUInt16LE(at + 28);
    const name = zip.subarray(at + 30, at + 30 + nameLength).toString("utf8");
    const data = at + 30 + nameLength + extraLength;
    if (method !== 0) throw new Error(`${path}: ${name} is compressed (method ${method})`);
    out[name.replace(/\.npy$/, "")] = parseNpy(zip.subarray(data, data + size));
    at = data + size;
  }
  return out;
}
