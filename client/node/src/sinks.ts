// Where the blocks of a dense matrix go as they arrive: a typed array, or a
// file (.npy, or raw little-endian values) written in place, so that a
// matrix larger than memory never is held whole. Blocks come as the wire's
// packed little-endian bytes, in a Buffer that views the decoded message at
// any byte offset: a Float64Array cannot view it (its offset must be a
// multiple of 8), so the bytes are copied into the destination instead.
import { promises as fs } from "node:fs";
import { endianness } from "node:os";

export type Dtype = "float32" | "float64";
export type MatrixArray = Float32Array | Float64Array;

export const ITEM_BYTES: Record<Dtype, number> = { float32: 4, float64: 8 };

const LITTLE_ENDIAN = endianness() === "LE";

/** A block of packed little-endian values as a fresh, aligned array (a copy: see above). */
export function unpack(bytes: Uint8Array, dtype: Dtype, count: number): MatrixArray {
  const item = ITEM_BYTES[dtype];
  if (bytes.length !== count * item) {
    throw new Error(`the server sent ${bytes.length} bytes for ${count} ${dtype} values`);
  }
  const out = dtype === "float32" ? new Float32Array(count) : new Float64Array(count);
  if (LITTLE_ENDIAN) {
    new Uint8Array(out.buffer).set(bytes);
  } else {
    const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    for (let i = 0; i < count; i++) {
      out[i] = dtype === "float32" ? view.getFloat32(i * 4, true) : view.getFloat64(i * 8, true);
    }
  }
  return out;
}

/** What a dense matrix is written to. Blocks are rows x cols values, row-major, placed at
 * (firstRow, firstCol) of the whole matrix. */
export interface Sink {
  readonly rows: number;
  readonly cols: number;
  readonly dtype: Dtype;
  /** Packed little-endian values of the sink's dtype. */
  writePacked(firstRow: number, firstCol: number, rows: number, cols: number,
    bytes: Uint8Array): Promise<void>;
  /** Values as numbers (an older server's float64 answers), rounded to the sink's dtype. */
  writeValues(firstRow: number, firstCol: number, rows: number, cols: number,
    values: ArrayLike<number>): Promise<void>;
}

function checkBlock(sink: Sink, firstRow: number, firstCol: number, rows: number,
  cols: number): void {
  if (firstRow + rows > sink.rows || firstCol + cols > sink.cols) {
    throw new Error(`a ${rows} x ${cols} block at (${firstRow}, ${firstCol}) passes the ` +
      `${sink.rows} x ${sink.cols} matrix`);
  }
}

/** A typed array, row-major. */
export class ArraySink implements Sink {
  constructor(readonly rows: number, readonly cols: number, readonly dtype: Dtype,
    readonly data: MatrixArray) {
    if (data.length !== rows * cols) {
      throw new RangeError(`out: ${data.length} values for a ${rows} x ${cols} matrix`);
    }
  }

  async writePacked(firstRow: number, firstCol: number, rows: number, cols: number,
    bytes: Uint8Array): Promise<void> {
    checkBlock(this, firstRow, firstCol, rows, cols);
    const block = unpack(bytes, this.dtype, rows * cols);
    this.place(firstRow, firstCol, rows, cols, block);
  }

  async writeValues(firstRow: number, firstCol: number, rows: number, cols: number,
    values: ArrayLike<number>): Promise<void> {
    checkBlock(this, firstRow, firstCol, rows, cols);
    if (values.length !== rows * cols) {
      throw new Error(`the server sent ${values.length} values for a ${rows} x ${cols} block`);
    }
    const block = this.dtype === "float32" ? Float32Array.from(values) : Float64Array.from(values);
    this.place(firstRow, firstCol, rows, cols, block);
  }

  private place(firstRow: number, firstCol: number, rows: number, cols: number,
    block: MatrixArray): void {
    if (firstCol === 0 && cols === this.cols) {
      this.data.set(block, firstRow * this.cols);
      return;
    }
    for (let r = 0; r < rows; r++) {
      const row = block.subarray(r * cols, (r + 1) * cols);
      this.data.set(row, (firstRow + r) * this.cols + firstCol);
    }
  }
}

/** The .npy header (format 1.0) of a C-order little-endian matrix. */
export function npyHeader(rows: number, cols: number, dtype: Dtype): Buffer {
  const dict = `{'descr': '<f${ITEM_BYTES[dtype]}', 'fortran_order': False, ` +
    `'shape': (${rows}, ${cols}), }`;
  // Magic (6), version (2), header length (2), then the dict padded with
  // spaces and ended by a newline to a multiple of 64 bytes.
  const total = Math.ceil((10 + dict.length + 1) / 64) * 64;
  const header = Buffer.alloc(total, 0x20);
  header.write("\x93NUMPY", 0, "latin1");
  header[6] = 1;
  header[7] = 0;
  header.writeUInt16LE(total - 10, 8);
  header.write(dict, 10, "latin1");
  header[total - 1] = 0x0a;
  return header;
}

/** A file: .npy (numpy.load reads it) or, for any other extension, the raw little-endian
 * values, row-major. Written to PATH.part and renamed when complete, so that the file
 * appears whole or not at all. */
export class FileSink implements Sink {
  private constructor(readonly rows: number, readonly cols: number, readonly dtype: Dtype,
    readonly path: string, private readonly file: fs.FileHandle,
    private readonly headerBytes: number) {}

  static async open(path: string, rows: number, cols: number, dtype: Dtype): Promise<FileSink> {
    const header = path.toLowerCase().endsWith(".npy") ? npyHeader(rows, cols, dtype)
      : Buffer.alloc(0);
    const file = await fs.open(`${path}.part`, "w");
    try {
      await file.write(header, 0, header.length, 0);
      // Sized up front: blocks are written in place, in any order.
      await file.truncate(header.length + rows * cols * ITEM_BYTES[dtype]);
    } catch (e) {
      await file.close();
      await fs.rm(`${path}.part`, { force: true });
      throw e;
    }
    return new FileSink(rows, cols, dtype, path, file, header.length);
  }

  async writePacked(firstRow: number, firstCol: number, rows: number, cols: number,
    bytes: Uint8Array): Promise<void> {
    checkBlock(this, firstRow, firstCol, rows, cols);
    const item = ITEM_BYTES[this.dtype];
    if (bytes.length !== rows * cols * item) {
      throw new Error(`the server sent ${bytes.length} bytes for a ${rows} x ${cols} block`);
    }
    if (firstCol === 0 && cols === this.cols) {
      await this.writeAt(bytes, firstRow * this.cols);
      return;
    }
    for (let r = 0; r < rows; r++) {
      await this.writeAt(bytes.subarray(r * cols * item, (r + 1) * cols * item),
        (firstRow + r) * this.cols + firstCol);
    }
  }

  async writeValues(firstRow: number, firstCol: number, rows: number, cols: number,
    values: ArrayLike<number>): Promise<void> {
    const block = this.dtype === "float32" ? Float32Array.from(values) : Float64Array.from(values);
    const bytes = Buffer.alloc(block.byteLength);
    const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    block.forEach((v, i) => {
      if (this.dtype === "float32") view.setFloat32(i * 4, v, true);
      else view.setFloat64(i * 8, v, true);
    });
    await this.writePacked(firstRow, firstCol, rows, cols, bytes);
  }

  private async writeAt(bytes: Uint8Array, index: number): Promise<void> {
    let done = 0;
    const position = this.headerBytes + index * ITEM_BYTES[this.dtype];
    while (done < bytes.length) {
      const { bytesWritten } = await this.file.write(bytes, done, bytes.length - done,
        position + done);
      done += bytesWritten;
    }
  }

  /** Closes the file: renamed into place when `complete`, removed otherwise. */
  async finish(complete: boolean): Promise<void> {
    await this.file.close();
    if (complete) await fs.rename(`${this.path}.part`, this.path);
    else await fs.rm(`${this.path}.part`, { force: true });
  }
}
