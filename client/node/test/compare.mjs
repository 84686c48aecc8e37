// Bit-for-bit comparison of two answers, after asserting that both are real:
// non-empty, and finite where a connected mesh's distances must be.
import assert from "node:assert/strict";

function bytes(a) {
  return Buffer.from(a.buffer, a.byteOffset, a.byteLength);
}

/** `got` and `want` (typed arrays) hold the same values bit for bit; both non-empty and, but
 * for `allowInfinite`, every value finite (NaN never). */
export function assertSameBits(got, want, what, { allowInfinite = false } = {}) {
  for (const [side, a] of [["client", got], ["offline", want]]) {
    assert.ok(a && a.length > 0, `${what}: the ${side} answer is empty`);
    for (let i = 0; i < a.length; i++) {
      const v = Number(a[i]);
      assert.ok(allowInfinite ? !Number.isNaN(v) : Number.isFinite(v),
        `${what}: the ${side} answer's [${i}] is ${v}`);
    }
  }
  assert.equal(got.constructor.name, want.constructor.name, `${what}: element types`);
  assert.equal(got.length, want.length, `${what}: lengths`);
  if (!bytes(got).equals(bytes(want))) {
    const i = got.findIndex((v, k) => !Object.is(v, want[k]));
    assert.fail(`${what}: [${i}] is ${got[i]} from the client, ${want[i]} offline`);
  }
}
