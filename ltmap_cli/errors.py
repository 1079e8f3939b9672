"""The project's error classes.

Every failure a user can cause is raised as an ``LtmapError`` subclass whose message is one
line: what is wrong, where (file, topic, message index, SVG element id) and what to do. The CLI
turns it into that line on stderr and exit status 2; nothing below the CLI prints or exits.
One class per package, as rosbags does.
"""


from collections.abc import Iterable

LIST_ITEMS = 10  # items an error line lists at most
LIST_CHARS = 400  # characters a listed run of items takes at most


def bounded(items: Iterable[object], limit: int = LIST_ITEMS, max_chars: int = LIST_CHARS, sep: str = ", ",
            empty: str = "none") -> str:
    """``items`` joined with ``sep`` for a one-line error, cut after ``limit`` items or
    ``max_chars`` characters with "... N more" (a RealSense recording has ~70 topics)."""
    items = [str(i) for i in items]
    if not items:
        return empty
    shown: list[str] = []
    size = 0
    for item in items:
        if len(shown) >= limit or (shown and size + len(sep) + len(item) > max_chars):
            break
        shown.append(item)
        size += len(item) + (len(sep) if len(shown) > 1 else 0)
    rest = len(items) - len(shown)
    return sep.join(shown) + (f"{sep}... {rest} more" if rest else "")


class LtmapError(Exception):
    """Base class of every error ltmap reports to a user (exit status 2)."""

    exit_code = 2


INTERRUPTED = 130  # the exit status after Ctrl-C: 128 + SIGINT, as shells give it


class RunInterrupted(LtmapError):
    """The user stopped the run (Ctrl-C) before it had anything to write (exit status
    ``INTERRUPTED``)."""

    exit_code = INTERRUPTED


class ConfigError(LtmapError):
    """A parameter or configuration file is invalid."""


class CoreError(LtmapError):
    """The map core was given inconsistent input (shapes, resolutions, states)."""


class InputError(LtmapError):
    """A file given on the command line is missing, empty or of the wrong kind."""


class LogReadError(InputError):
    """A log (bag / MCAP) cannot be read, or is truncated or corrupt."""


class MapFileError(InputError):
    """A map file (map_server YAML + image, snapshot, state file) cannot be read."""


class KernelCacheError(LtmapError):
    """numba's disk cache of the compiled kernels holds a file it cannot read (a cache copied in
    part, a damaged disk)."""


class OutputError(LtmapError):
    """An output folder or file cannot be written (not a folder, no permission, disk full)."""


def output_error(err: OSError, what: str) -> OutputError:
    """One line for an OSError met while writing ``what``."""
    return OutputError(f"cannot write {what}: {err.strerror or err}; choose another output path (-o)")


def human(n: float) -> str:
    """A byte count for a message: 512.0 B, 7.9 MB, 1.4 GB."""
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TB"


def first_line(err: BaseException, limit: int | None = None) -> str:
    """What a library's exception says, as one line of an ltmap message: its first line (cut to
    ``limit`` characters), or its type's name when it says nothing."""
    text = str(err).strip()
    return text.splitlines()[0][:limit] if text else type(err).__name__


class TransformError(LtmapError):
    """A transform needed to place sensor frames is missing."""


class PlanError(LtmapError):
    """An SVG floor plan cannot be turned into a static map."""


class NoPathError(LtmapError):
    """The planner found no path (exit status 1, like a search that found nothing)."""

    exit_code = 1


class LtmapWarning(UserWarning):
    """Something a user should know that does not stop the run (a damaged message skipped).

    Raised with ``warnings.warn`` below the CLI; the CLI prints it as one ``ltmap: warning:`` line."""


def shown(value: object, limit: int = 80) -> str:
    """``value`` as a message shows it: its repr cut to about ``limit`` characters ("... N more"),
    built within that budget, so that a huge or deeply shared value (a YAML alias bomb, a
    kilobyte string) costs no more than its cut text."""
    text = _bounded_repr(value, limit + 1, 0)
    if len(text) <= limit:
        return text
    more = _length(value)
    return text[:limit] + (f"... ({more} in all)" if more else "...")


def _length(value: object) -> str:
    if isinstance(value, (str, bytes)):
        return f"{len(value)} characters" if isinstance(value, str) else f"{len(value)} bytes"
    if isinstance(value, (list, tuple, dict, set)):
        return f"{len(value)} items"
    return ""


def _bounded_repr(value: object, budget: int, depth: int) -> str:
    if isinstance(value, (str, bytes)):
        return repr(value[:budget])
    if isinstance(value, (list, tuple, set, dict)) and depth < 8:
        items = value.items() if isinstance(value, dict) else value
        left, parts = budget, []
        for item in items:
            if left <= 0:
                parts.append("...")
                break
            if isinstance(value, dict):
                k, v = item
                part = f"{_bounded_repr(k, left, depth + 1)}: {_bounded_repr(v, left, depth + 1)}"
            else:
                part = _bounded_repr(item, left, depth + 1)
            parts.append(part)
            left -= len(part) + 2
        body = ", ".join(parts)
        if isinstance(value, dict):
            return "{" + body + "}"
        if isinstance(value, list):
            return "[" + body + "]"
        return "(" + body + ")" if isinstance(value, tuple) else "{" + body + "}"
    if isinstance(value, (list, tuple, set, dict)):
        return "[...]"
    return repr(value)[:budget]
