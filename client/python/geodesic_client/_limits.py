"""What the client believes of the server's per-call limits, and how it learns lower ones.

A call over a limit is refused RESOURCE_EXHAUSTED with each limit it passed as a trailer
("limit-max-pairs: 10000"; a matrix carries limit-max-sources and limit-max-pairs, an answer
over the message cap limit-max-message-bytes). An overloaded server refuses with a
retry-after-ms trailer instead, and no limit-* one: the transport retries those.
"""
from dataclasses import dataclass
from typing import Dict, Optional

from ._errors import GeodesicError, ResourceExhaustedError

# The server's defaults (geodesicd serve --max-pairs, --max-sources; its gRPC
# messages are limited to 64 MiB either way).
DEFAULT_MAX_PAIRS = 10000
DEFAULT_MAX_SOURCES = 1024
DEFAULT_MAX_MESSAGE_BYTES = 64 << 20
# Pairs per Distance call when paths are wanted: a path can hold thousands of
# points, so that whole batches stay far below the message size.
DEFAULT_PATH_BATCH = 256

# The limits' trailers: "limit-" and the server's flag.
MAX_PAIRS = "max-pairs"
MAX_SOURCES = "max-sources"
MAX_EXACT_PAIRS = "max-exact-pairs"
MAX_MESSAGE_BYTES = "max-message-bytes"
_PREFIX = "limit-"


def refused_limits(error: GeodesicError) -> Dict[str, int]:
    """The limits a RESOURCE_EXHAUSTED refusal says the call passed, by name ("max-pairs":
    10000); empty for any other error, an overload among them."""
    if not isinstance(error, ResourceExhaustedError):
        return {}
    limits = {}
    for key, value in error._trailers:
        if key.startswith(_PREFIX):
            try:
                limits[key[len(_PREFIX):]] = int(value)
            except ValueError:
                pass  # not a number: as if absent
    return limits


def over_message_cap(error: GeodesicError) -> bool:
    """True for an answer refused because it would pass the server's message cap."""
    return MAX_MESSAGE_BYTES in refused_limits(error)


def over_matrix_limits(error: GeodesicError) -> bool:
    """True for a matrix refused because of its sources or targets."""
    limits = refused_limits(error)
    return MAX_SOURCES in limits or MAX_PAIRS in limits


@dataclass
class Limits:
    """The batch sizes the client splits its calls by, lowered to the server's as it learns
    them from refusals."""

    max_pairs: int = DEFAULT_MAX_PAIRS
    max_sources: int = DEFAULT_MAX_SOURCES
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES
    path_batch: int = DEFAULT_PATH_BATCH

    def learn(self, error: GeodesicError, name: str, size: int) -> bool:
        """After a refusal naming limit `name` ("max-pairs" or "max-sources") below `size`,
        lowers that limit to it and returns True (retry); otherwise False."""
        limit = refused_limits(error).get(name, 0)
        if not 0 < limit < size:
            return False
        setattr(self, name.replace("-", "_"), limit)
        return True

    def learn_matrix(self, error: GeodesicError) -> bool:
        """After a matrix refused for smaller limits than these, adopts them (True: tile
        again)."""
        if not over_matrix_limits(error):
            return False
        limits = refused_limits(error)
        max_sources = limits.get(MAX_SOURCES, self.max_sources)
        max_targets = limits.get(MAX_PAIRS, self.max_pairs)
        if not (0 < max_sources < self.max_sources or 0 < max_targets < self.max_pairs):
            return False
        self.max_sources = min(self.max_sources, max(1, max_sources))
        self.max_pairs = min(self.max_pairs, max(1, max_targets))
        return True

    def smaller_pair_batch(self, error: GeodesicError, size: int,
                           with_path: bool) -> Optional[int]:
        """The Distance batch to retry with after a refusal of one of `size` pairs (learning
        the server's max_pairs, and path_batch with paths), or None to give up."""
        if not isinstance(error, ResourceExhaustedError):
            return None
        limits = refused_limits(error)
        # An exact cap (--max-exact-pairs) says nothing of graph pairs: only max-pairs is learnt.
        learnt = limits.get(MAX_PAIRS, 0)
        limit = learnt or limits.get(MAX_EXACT_PAIRS, 0)
        if 0 < limit < size:
            smaller = limit
        # An answer over the message cap: the server's (its trailer) or the channel's own
        # (gRPC's "larger than max", with no trailer).
        elif (MAX_MESSAGE_BYTES in limits or "larger than max" in error.details()) and size > 1:
            smaller = size // 2
        else:
            return None
        if with_path:
            self.path_batch = smaller
        if 0 < learnt == smaller < self.max_pairs:
            self.max_pairs = smaller
        return smaller
