// 64-bit proto fields as numbers. The loader decodes them as decimal strings
// (wire.ts says why); arithmetic on those concatenates ("0" + 1 is "01"), so
// every such field passes through here before the client uses it. A count
// or size fits a double exactly far beyond any mesh; one that does not is an
// error rather than a silently rounded number. Fields that may hold any
// 64-bit value (a seed) become bigints.
import type { Int64 } from "./wire";

// Accepts what a loader may produce: a string, a number, or a Long-like
// object (proto-loader's default), whose toString() is its decimal value.
type Int64Like = Int64 | bigint | { toString(): string } | null | undefined;

function asBigInt(value: Int64Like, field: string): bigint {
  if (value === null || value === undefined) return 0n;
  if (typeof value === "bigint") return value;
  if (typeof value === "number") {
    if (!Number.isInteger(value)) throw new RangeError(`${field}: ${value} is not an integer`);
    return BigInt(value);
  }
  const text = value.toString();
  if (!/^-?\d+$/.test(text)) {
    throw new RangeError(`${field}: ${JSON.stringify(text)} is not an integer`);
  }
  return BigInt(text);
}

/** A 64-bit field as a number: exact, or a RangeError naming the field. */
export function toNumber(value: Int64Like, field: string): number {
  if (typeof value === "number" && Number.isSafeInteger(value)) return value;
  const big = asBigInt(value, field);
  if (big > BigInt(Number.MAX_SAFE_INTEGER) || big < BigInt(Number.MIN_SAFE_INTEGER)) {
    throw new RangeError(`${field}: ${big} is beyond 2^53, the integers a number holds exactly`);
  }
  return Number(big);
}

/** A 64-bit field that may use all 64 bits, as a bigint. */
export function toBigInt(value: Int64Like, field: string): bigint {
  return asBigInt(value, field);
}

/** A non-negative integer for a uint64 request field, as the decimal string the loader sends
 * exactly (a number above 2^53 could not be). */
export function toUint64(value: number | bigint, field: string): string {
  const big = typeof value === "bigint" ? value : asBigInt(value, field);
  if (big < 0n || big >= 1n << 64n) throw new RangeError(`${field}: ${value} is not a uint64`);
  return big.toString();
}
