// What the client believes of the server's per-call limits, and how it
// learns lower ones. A call over a limit is refused RESOURCE_EXHAUSTED with
// each limit it passed as a trailer ("limit-max-pairs: 10000"; a matrix
// carries limit-max-sources and limit-max-pairs, an answer over the message
// cap limit-max-message-bytes). An overloaded server refuses with
// retry-after-ms and no limit-* trailer instead: retry.ts handles those.
import { GeodesicError, ResourceExhaustedError } from "./errors";

// The server's defaults (geodesicd serve --max-pairs, --max-sources; its
// gRPC messages are limited to 64 MiB either way).
export const DEFAULT_MAX_PAIRS = 10000;
export const DEFAULT_MAX_SOURCES = 1024;
export const DEFAULT_MAX_MESSAGE_BYTES = 64 << 20;
// Pairs per Distance call when paths are wanted: a path can hold thousands
// of points, so that whole batches stay far below the message size.
export const DEFAULT_PATH_BATCH = 256;

export const MAX_PAIRS = "max-pairs";
export const MAX_SOURCES = "max-sources";
const MAX_EXACT_PAIRS = "max-exact-pairs";
const MAX_MESSAGE_BYTES = "max-message-bytes";

function refused(error: GeodesicError): Readonly<Record<string, number>> {
  return error instanceof ResourceExhaustedError ? error.limits : {};
}

/** True for an answer refused because it would pass the server's message cap. */
export function overMessageCap(error: GeodesicError): boolean {
  return MAX_MESSAGE_BYTES in refused(error);
}

/** True for a matrix refused because of its sources or targets. */
export function overMatrixLimits(error: GeodesicError): boolean {
  const limits = refused(error);
  return MAX_SOURCES in limits || MAX_PAIRS in limits;
}

/** The batch sizes the client splits its calls by, lowered to the server's as it learns them
 * from refusals. */
export class Limits {
  constructor(public maxPairs = DEFAULT_MAX_PAIRS, public maxSources = DEFAULT_MAX_SOURCES,
    public maxMessageBytes = DEFAULT_MAX_MESSAGE_BYTES, public pathBatch = DEFAULT_PATH_BATCH) {}

  /** After a refusal naming limit `name` (MAX_PAIRS or MAX_SOURCES) below `size`, lowers that
   * limit to it and returns true (retry); otherwise false. */
  learn(error: GeodesicError, name: typeof MAX_PAIRS | typeof MAX_SOURCES, size: number): boolean {
    const limit = refused(error)[name] ?? 0;
    if (!(limit > 0 && limit < size)) return false;
    if (name === MAX_PAIRS) this.maxPairs = limit;
    else this.maxSources = limit;
    return true;
  }

  /** After a matrix refused for smaller limits than these, adopts them (true: tile again). */
  learnMatrix(error: GeodesicError): boolean {
    if (!overMatrixLimits(error)) return false;
    const limits = refused(error);
    const sources = limits[MAX_SOURCES] ?? this.maxSources;
    const targets = limits[MAX_PAIRS] ?? this.maxPairs;
    if (!((sources > 0 && sources < this.maxSources) || (targets > 0 && targets < this.maxPairs))) {
      return false;
    }
    this.maxSources = Math.min(this.maxSources, Math.max(1, sources));
    this.maxPairs = Math.min(this.maxPairs, Math.max(1, targets));
    return true;
  }

  /** The Distance batch to retry with after a refusal of one of `size` pairs (learning the
   * server's maxPairs, and pathBatch with paths), or null to give up. */
  smallerPairBatch(error: GeodesicError, size: number, withPath: boolean): number | null {
    if (!(error instanceof ResourceExhaustedError)) return null;
    const limits = refused(error);
    // An exact cap (--max-exact-pairs) says nothing of graph pairs: only
    // max-pairs is learnt.
    const learnt = limits[MAX_PAIRS] ?? 0;
    const limit = learnt || (limits[MAX_EXACT_PAIRS] ?? 0);
    let smaller: number;
    if (limit > 0 && limit < size) {
      smaller = limit;
    } else if ((MAX_MESSAGE_BYTES in limits || error.details.includes("larger than max")) &&
      size > 1) {
      // Over the server's message cap (its trailer) or the channel's own
      // (gRPC's "larger than max", with no trailer): halve.
      smaller = Math.floor(size / 2);
    } else {
      return null;
    }
    if (withPath) this.pathBatch = smaller;
    if (learnt > 0 && learnt === smaller && smaller < this.maxPairs) this.maxPairs = smaller;
    return smaller;
  }
}
