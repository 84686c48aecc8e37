// Retries of failed calls: which failures are worth another attempt, and how
// long to wait before it. The server's hint (retry-after-ms) is a floor on
// the wait: it says when a graph may be done or the overload over, and a
// client that comes back sooner only adds to the load it was refused for.
import { GeodesicError, ResourceExhaustedError } from "./errors";

/** Retries of calls failing with a transient status, with jittered exponential backoff (the
 * Python client's RetryPolicy, the same defaults).
 *
 * The n-th retry waits a random time in [d/2, d], d = min(initialBackoff * multiplier^(n-1),
 * maxBackoff) seconds, and at least the server's retry-after-ms hint. maxAttempts counts the
 * first call; 1 disables retries. UNAVAILABLE is what the server answers while a graph is
 * still building or loading, and what gRPC reports while the server cannot be reached. With
 * `overload`, RESOURCE_EXHAUSTED answers that say the server is overloaded (those carrying
 * retry-after-ms; never a limit the request itself passed) are retried too. */
export interface RetryPolicy {
  readonly maxAttempts: number;
  /** Seconds. */
  readonly initialBackoff: number;
  readonly multiplier: number;
  /** Seconds. */
  readonly maxBackoff: number;
  /** Status code names retried ("UNAVAILABLE", ...). */
  readonly codes: readonly string[];
  readonly overload: boolean;
  /** Called before each retry's wait: the failure, the wait (ms) and the attempt that failed
   * (1 for the first call). For logging; an exception it throws ends the retries. */
  readonly onRetry?: (error: GeodesicError, delayMs: number, attempt: number) => void;
}

export const DEFAULT_RETRY: RetryPolicy = Object.freeze({
  maxAttempts: 8,
  initialBackoff: 0.1,
  multiplier: 2.0,
  maxBackoff: 2.0,
  codes: Object.freeze(["UNAVAILABLE"]),
  overload: true,
});

/** A policy: the defaults with `overrides`. */
export function retryPolicy(overrides: Partial<RetryPolicy> = {}): RetryPolicy {
  const policy = { ...DEFAULT_RETRY, ...overrides };
  if (!Number.isInteger(policy.maxAttempts) || policy.maxAttempts < 1) {
    throw new RangeError(`retry.maxAttempts ${policy.maxAttempts} is not an integer >= 1`);
  }
  for (const key of ["initialBackoff", "multiplier", "maxBackoff"] as const) {
    if (!(Number.isFinite(policy[key]) && policy[key] >= 0)) {
      throw new RangeError(`retry.${key} ${policy[key]} is not a finite number >= 0`);
    }
  }
  return Object.freeze(policy);
}

/** Whether `error` is one the policy retries. */
export function retryable(policy: RetryPolicy, error: GeodesicError): boolean {
  if (policy.codes.includes(error.codeName)) return true;
  return policy.overload && error instanceof ResourceExhaustedError && error.overloaded;
}

/** Milliseconds to wait after attempt number `attempt` (1-based) failed with `error`, or null
 * when the policy gives up. `random` is in [0, 1) (Math.random; a test fixes it). */
export function retryDelayMs(policy: RetryPolicy, error: GeodesicError, attempt: number,
  random: () => number = Math.random): number | null {
  if (attempt >= policy.maxAttempts || !retryable(policy, error)) return null;
  const backoff = Math.min(policy.initialBackoff * policy.multiplier ** (attempt - 1),
    policy.maxBackoff) * 1000;
  const jittered = backoff / 2 + random() * (backoff / 2);
  return Math.max(error.retryAfterMs ?? 0, jittered);
}

const sleep = (ms: number): Promise<void> => new Promise((resolve) => setTimeout(resolve, ms));

/** run() until it succeeds or fails in a way the policy does not retry. `run` must convert
 * gRPC failures to GeodesicError (transport.ts does); anything else is thrown at once. */
export async function withRetries<T>(policy: RetryPolicy, run: () => Promise<T>): Promise<T> {
  for (let attempt = 1; ; attempt++) {
    try {
      return await run();
    } catch (e) {
      if (!(e instanceof GeodesicError)) throw e;
      const delay = retryDelayMs(policy, e, attempt);
      if (delay === null) throw e;
      policy.onRetry?.(e, delay, attempt);
      await sleep(delay);
    }
  }
}
