"""What a log reader may leave unread before a time (``replay --start``): one rule for every
format that can seek (MCAP chunks, ROS 1 bag chunks)."""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SkipBefore:
    """What a reader may leave unread: messages logged before ``ns``, except every message of the
    ``keep_all`` topics (/tf_static) and the last one before ``ns`` of the ``keep_last`` topics
    (CameraInfo). A hint: a source that cannot seek reads them anyway (the caller filters)."""

    ns: int
    keep_all: frozenset = frozenset()
    keep_last: frozenset = frozenset()


def unread_chunks(early: Sequence[Any], holds: Callable[[Any], Iterable[Hashable]], order: Callable[[Any], Any],
                  keep_all: frozenset, keep_last: frozenset) -> set[int]:  # fmt: skip
    """Indexes in ``early`` (chunks whose messages all lie before the skip time) of those that need
    not be read: every chunk but those holding a ``keep_all`` key and, for each ``keep_last`` key,
    the last chunk holding it (by ``order``). ``holds(chunk)``: the keys it holds (topics or
    connection ids, as the keep sets)."""
    held = [set(holds(c)) for c in early]
    keep = {i for i, h in enumerate(held) if keep_all & h}
    for key in keep_last:
        holding = [i for i, h in enumerate(held) if key in h]
        if holding:
            keep.add(max(holding, key=lambda i: order(early[i])))
    return {i for i in range(len(early)) if i not in keep}
