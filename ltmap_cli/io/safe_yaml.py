"""The one YAML loader of ltmap: config files, ``--set`` values, map YAMLs, scenarios and ROS 2
``metadata.yaml`` are all read here.

- Safe (plain data only), with libyaml's C parser when available.
- Bounded: a file larger than ``MAX_YAML_BYTES`` is refused before it is read, and only regular
  files are read (a FIFO or a device would hang or never end). Anchors and aliases are allowed,
  but the document they expand to is counted before it is built: more than ``MAX_YAML_NODES``
  nodes (a "billion laughs" alias bomb of a few hundred bytes expands to 10^9) is refused.
- Numbers as YAML 1.2 and every JSON/Python user writes them: ``1e9``, ``-2.5E-3`` and ``1e+9``
  are floats (PyYAML's YAML 1.1 rules read ``1e9`` as a string).

Errors are raised as the exception class the caller gives (``ConfigError``, ``MapFileError``,
...) with one line naming the file and the fault.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import yaml

MAX_YAML_BYTES = 64 * 2**20  # a ROS 2 metadata.yaml of thousands of files is a few MB
MAX_YAML_NODES = 1_000_000  # nodes after expanding aliases; a config has a few hundred

_Base = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+][0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)


class _Loader(_Base):  # type: ignore[misc, valid-type]
    """Safe loader whose floats include ``1e9`` (YAML 1.2)."""


# replace the float resolver (copying the table, not touching PyYAML's own loaders)
_Loader.yaml_implicit_resolvers = {
    ch: [(tag, rx) for tag, rx in lst if tag != "tag:yaml.org,2002:float"]
    for ch, lst in _Base.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))


class YamlLimitError(ValueError):
    """The document is too large once its aliases are expanded."""


def _expanded_nodes(text: str, limit: int) -> int:
    """The node count of the document with every alias expanded; raises ``YamlLimitError``
    as soon as it passes ``limit`` (the events are read once, nothing is built)."""
    sizes: dict[str, int] = {}
    stack: list[list] = [[0, None]]
    total = 0
    for ev in yaml.parse(text, Loader=_Base):
        if isinstance(ev, yaml.AliasEvent):
            n = sizes.get(ev.anchor, 1)
        elif isinstance(ev, yaml.ScalarEvent):
            n = 1
            if ev.anchor:
                sizes[ev.anchor] = 1
        elif isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            stack.append([1, ev.anchor])
            total += 1
            continue
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            n, anchor = stack.pop()
            if anchor:
                sizes[anchor] = n
            stack[-1][0] += n
            continue
        else:
            continue
        stack[-1][0] += n
        total += n
        if total > limit or stack[-1][0] > limit:
            raise YamlLimitError(f"expands to more than {limit:,} nodes through its aliases (&anchor / *alias)")
    return total


def loads(text: str, max_nodes: int = MAX_YAML_NODES) -> Any:
    """Parse YAML text (safe, bounded); raises ``yaml.YAMLError`` or ``YamlLimitError``."""
    if "*" in text:  # only aliases can expand; plain documents are parsed once
        _expanded_nodes(text, max_nodes)
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a safe loader


def check_regular_file(path: Path, what: str, error: type[Exception], max_bytes: int | None = None) -> int:
    """``os.stat`` the path and refuse, in one line, anything but a regular file (a FIFO, a
    device such as /dev/zero, a folder) and files over ``max_bytes``; returns the size."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found; check the path") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc}); check the path") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, not a {what} file; give the file")
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else (
            "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file")
        raise error(f"{path}: is {kind}, not a {what} file; give a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(f"{path}: the {what} is {st.st_size / 2**20:.1f} MB, more than a {what} can be "
                    f"({max_bytes / 2**20:.0f} MB); give the right file")
    return int(st.st_size)


def load_file(path: str | Path, what: str, error: type[Exception], max_bytes: int = MAX_YAML_BYTES,
              trailing_separator: bool = False) -> Any:
    """Read and parse a YAML file: one line (``error``) naming the file and the fault.
    ``trailing_separator``: a document separator (``---`` / ``...``) on the last lines is dropped
    (``ros2 topic echo`` ends each message with one)."""
    p = Path(path)
    check_regular_file(p, what, error, max_bytes)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise error(f"{p}: the {what} is not UTF-8 text; give a YAML file") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {what} ({exc.strerror or exc}); check the file") from None
    if trailing_separator:
        lines = text.rstrip().splitlines()
        while lines and lines[-1].strip() in ("---", "..."):
            lines.pop()
        text = "\n".join(lines) + "\n"
    try:
        return loads(text)
    except YamlLimitError as exc:
        raise error(f"{p}: the {what} {exc}; write it out plainly") from None
    except yaml.YAMLError as exc:
        raise error(f"{p}: not valid YAML{_where(exc)}; fix the {what}") from None


def _where(exc: Exception) -> str:
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return where + (f" ({problem})" if problem else "")


__all__ = ["loads", "load_file", "check_regular_file", "YamlLimitError", "MAX_YAML_BYTES", "MAX_YAML_NODES"]
