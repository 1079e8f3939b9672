"""The fleet manifest (SPEC 5, ``ltmap batch FLEET.yaml``), read and checked before any work.

```yaml
config: fleet.yaml                 # optional: parameters for every site (a YAML file or a mapping)
sites:
  lab:
    static: plans/lab.svg          # optional: an SVG plan, a map_server YAML or a build-static folder
    static_options: {scale: 0.01}  # optional, SVG only: build-static's options
    config: {replay: {tf: [...]}}  # optional: parameters for this site (file or mapping)
    days:                          # in order; each day is one or more logs replayed together
      - [logs/lab/mon.mcap]
      - [logs/lab/tue_a.bag, logs/lab/tue_b.bag]
```

Paths are relative to the manifest. Every problem is a ``ManifestError``: one line that names
the manifest and the entry (site, day, log) and says what to do; the CLI exits 2 on it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..config import Config, update_from_dict
from ..errors import ConfigError
from ..io import safe_yaml
from ..io.static_layer import LAYER_FILE, MAP_YAML

MANIFEST_KEYS = ("sites", "config")
SITE_KEYS = ("static", "static_options", "config", "days")
PLAN_SUFFIXES = (".svg",)
MAP_SUFFIXES = (".yaml", ".yml")
# build-static's options a site may give for its SVG plan (name -> what it must be)
STATIC_OPTIONS = {
    "scale": "a positive number (metres per SVG unit)",
    "resolution": "a positive number (m)",
    "wall_height": "a positive number (m)",
    "wall_thickness": "a positive number (m)",
    "origin": "[x, y, yaw] (m, m, rad)",
    "furniture": "none, static or long-term",
}
FURNITURE = ("none", "static", "long-term")
SITE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
MAX_MANIFEST_BYTES = 16 * 2**20  # a manifest is text; more is a mistake (or a bomb)
MAX_LOGS = 100_000  # logs in all days of all sites (YAML aliases can multiply a short file)


class ManifestError(ConfigError):
    """The fleet manifest is invalid (exit status 2, one line naming the entry)."""


@dataclass(frozen=True)
class Site:
    name: str
    days: tuple[tuple[Path, ...], ...]  # day i (from 0) -> its logs, absolute
    static: Path | None = None
    static_options: dict = field(default_factory=dict)
    config: dict = field(default_factory=dict)  # parameter overrides (config.yaml names), nested

    @property
    def static_is_plan(self) -> bool:
        """An SVG plan is built once into OUT/<site>/static/; a map YAML or a build-static folder
        is given to the replay as it is."""
        return self.static is not None and self.static.suffix.lower() in PLAN_SUFFIXES


@dataclass(frozen=True)
class Manifest:
    path: Path
    sites: tuple[Site, ...]
    config: dict = field(default_factory=dict)  # overrides for every site


def load_manifest(path: str | Path) -> Manifest:
    """Read and check FLEET.yaml: every log and static input exists, every key is known, every
    parameter is a valid config name and value. Raises ManifestError (one line)."""
    import yaml

    p = Path(path)
    if not p.is_file():
        what = "is a folder" if p.is_dir() else "is not a regular file" if p.exists() else "does not exist"
        raise ManifestError(f"manifest {p} {what}; give the fleet's YAML file (see docs/fleet.md)")
    size = p.stat().st_size
    if size > MAX_MANIFEST_BYTES:
        raise ManifestError(
            f"manifest {p} is {size / 2**20:.0f} MB, over {MAX_MANIFEST_BYTES // 2**20} MB; "
            "is it the right file?"
        )
    try:
        doc = safe_yaml.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ManifestError(f"manifest {p} is not UTF-8 text; give the fleet's YAML file") from None
    except (yaml.YAMLError, safe_yaml.YamlLimitError) as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise ManifestError(f"manifest {p}: not valid YAML{where} ({problem}); fix the syntax") from None
    return parse_manifest(doc, p)


def parse_manifest(doc: Any, path: Path) -> Manifest:
    """Check the loaded YAML ``doc`` of the manifest at ``path`` (paths are relative to it)."""
    base = path.parent

    def bad(where: str, what: str) -> ManifestError:
        return ManifestError(f"manifest {path}: {where}: {what}")

    if doc is None:
        raise ManifestError(f"manifest {path} is empty; it needs a 'sites:' mapping (see docs/fleet.md)")
    if not isinstance(doc, dict):
        raise bad("top level", f"expected a mapping with 'sites:', got {_kind(doc)}")
    _known_keys(doc, MANIFEST_KEYS, "top level", bad)
    config = _config_entry(doc.get("config"), "config", base, bad)
    sites_doc = doc.get("sites")
    if sites_doc is None:
        raise bad("top level", "no 'sites:' mapping; add one (site name -> static, days)")
    if not isinstance(sites_doc, dict) or not sites_doc:
        raise bad("sites", f"expected a mapping of site names to sites, got {_kind(sites_doc)}")
    sites, n_logs = [], 0
    for raw_name, site_doc in sites_doc.items():
        name = str(raw_name) if isinstance(raw_name, (str, int)) and not isinstance(raw_name, bool) else None
        if name is None or not SITE_NAME.match(name):
            raise bad(
                f"site {raw_name!r}",
                "a site name must be letters, digits, '.', '_' or '-' (it names the "
                "output folder OUT/<site>/), starting with a letter or digit",
            )
        where = f"sites.{name}"
        if not isinstance(site_doc, dict):
            raise bad(
                where, f"expected a mapping with 'days:' (and optionally 'static:'), got {_kind(site_doc)}"
            )
        _known_keys(site_doc, SITE_KEYS, where, bad)
        static = None
        if site_doc.get("static") is not None:
            static = _static_entry(site_doc["static"], f"{where}.static", base, bad)
        options = _static_options(site_doc.get("static_options"), static, f"{where}.static_options", bad)
        site_config = _config_entry(site_doc.get("config"), f"{where}.config", base, bad)
        _check_config([config, site_config], f"{where}.config" if site_config else "config", bad)
        days_doc = site_doc.get("days")
        if days_doc is None:
            raise bad(where, "no 'days:' list; add one: a list of days, each a list of logs")
        if not isinstance(days_doc, list) or not days_doc:
            raise bad(
                f"{where}.days",
                f"expected a non-empty list of days (each a list of logs), got {_kind(days_doc)}",
            )
        n_logs += sum(len(d) if isinstance(d, list) else 1 for d in days_doc)
        if n_logs > MAX_LOGS:
            raise bad(
                f"{where}.days",
                f"more than {MAX_LOGS} logs in the manifest; split the fleet into several manifests",
            )
        days = []
        for i, day in enumerate(days_doc, start=1):
            dwhere = f"{where}.days: day {i}"
            if not isinstance(day, list):
                hint = f"; write it as - [{_show(day)}]" if isinstance(day, str) else ""
                raise bad(dwhere, f"expected a list of logs, got {_kind(day)}{hint}")
            if not day:
                raise bad(dwhere, "is an empty list; give at least one log, or remove the day")
            logs = []
            for log in day:
                if not isinstance(log, str) or not log.strip():
                    raise bad(dwhere, f"a log must be a path, got {_kind(log)}")
                lp = _resolve(base, log)
                if not lp.exists():
                    raise bad(
                        f"{dwhere}, log {log}",
                        f"no such file or folder ({lp}); fix the path (relative to the manifest)",
                    )
                if not (lp.is_file() or lp.is_dir()):
                    raise bad(
                        f"{dwhere}, log {log}",
                        "is neither a file nor a folder; give a .bag, an .mcap or a ROS 2 bag folder",
                    )
                if lp in logs:
                    raise bad(f"{dwhere}, log {log}", "is listed twice in the same day; list it once")
                logs.append(lp)
            days.append(tuple(logs))
        sites.append(
            Site(name=name, days=tuple(days), static=static, static_options=options, config=site_config)
        )
    lower = {}
    for s in sites:  # lab and Lab would share a folder on a case-insensitive file system
        if s.name.lower() in lower:
            raise bad(
                f"sites.{s.name}", f"differs from site {lower[s.name.lower()]} only in case; rename one"
            )
        lower[s.name.lower()] = s.name
    return Manifest(path=path, sites=tuple(sites), config=config)


def _known_keys(doc: dict, known: tuple[str, ...], where: str, bad) -> None:
    for key in doc:
        if key not in known:
            raise bad(where, f"unknown key {key!r}; known keys here: {', '.join(known)}")


def _resolve(base: Path, text: str) -> Path:
    p = Path(text).expanduser()
    return (p if p.is_absolute() else base / p).absolute()


def _static_entry(value: Any, where: str, base: Path, bad) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise bad(
            where,
            f"expected the path of an SVG plan, a map YAML or a build-static folder, got {_kind(value)}",
        )
    p = _resolve(base, value)
    if not p.exists():
        raise bad(where, f"{value}: no such file or folder ({p}); fix the path (relative to the manifest)")
    if p.is_file() and p.suffix.lower() not in PLAN_SUFFIXES + MAP_SUFFIXES:
        raise bad(
            where,
            f"{value}: expected an SVG plan (.svg), a map_server YAML (.yaml) or a build-static "
            "output folder",
        )
    if p.is_dir() and not any((p / n).is_file() for n in (MAP_YAML, LAYER_FILE)):
        raise bad(
            where,
            f"{value}: this folder holds no static.yaml or static_layer.npz; give a build-static "
            "output folder, an SVG plan or a map YAML",
        )
    return p


def _static_options(value: Any, static: Path | None, where: str, bad) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise bad(where, f"expected a mapping of build-static options, got {_kind(value)}")
    if static is None or static.suffix.lower() not in PLAN_SUFFIXES:
        raise bad(
            where, "build-static options apply to an SVG plan only; give 'static: PLAN.svg' or remove them"
        )
    out = {}
    for key, v in value.items():
        if key not in STATIC_OPTIONS:
            raise bad(where, f"unknown option {key!r}; known options: {', '.join(STATIC_OPTIONS)}")
        if key == "furniture":
            ok = v in FURNITURE
        elif key == "origin":
            ok = isinstance(v, list) and len(v) == 3 and all(_number(x) for x in v)
            v = [float(x) for x in v] if ok else v
        else:
            ok = _number(v) and v > 0
            v = float(v) if ok else v
        if not ok:
            raise bad(f"{where}.{key}", f"must be {STATIC_OPTIONS[key]}, got {v!r}")
        out[key] = v
    return out


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _config_entry(value: Any, where: str, base: Path, bad) -> dict:
    """A 'config:' entry: a mapping of parameters, or the path of a YAML file of them."""
    if value is None:
        return {}
    if isinstance(value, str):
        p = _resolve(base, value)
        if not p.is_file():
            raise bad(
                where,
                f"{value}: no such file ({p}); give a YAML file of parameters (ltmap replay "
                "--dump-config writes one) or a mapping",
            )
        try:  # bounded as every YAML ltmap reads (size, aliases)
            value = safe_yaml.load_file(p, "config file", ManifestError) or {}
        except ManifestError as err:
            raise bad(where, str(err)) from None
    if not isinstance(value, dict):
        raise bad(
            where,
            f"expected a mapping of parameters (the names of config.yaml) or a file, got {_kind(value)}",
        )
    _check_config([value], where, bad)
    return value


def _check_config(layers: list[dict], where: str, bad) -> None:
    cfg = Config()
    try:
        for layer in layers:
            update_from_dict(cfg, layer)
        cfg.validate()
    except ConfigError as err:
        raise bad(where, f"{err}") from None


def _kind(v: Any) -> str:
    if v is None:
        return "nothing"
    if isinstance(v, dict):
        return "a mapping"
    if isinstance(v, list):
        return "a list"
    return f"{type(v).__name__} {_show(v)!r}" if not isinstance(v, str) else repr(_show(v))


def _show(v: Any, limit: int = 60) -> str:
    s = str(v)
    return s if len(s) <= limit else s[: limit - 3] + "..."
