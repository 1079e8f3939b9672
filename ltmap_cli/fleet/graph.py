"""The batch's tasks and their fingerprints.

Per site: one ``StaticTask`` when its static input is an SVG plan (built once into
``OUT/<site>/static/``); per site and sweep point a ``Chain`` of ``DayTask``s, day N resuming from
day N-1's folder. Chains are independent of each other (they run in parallel); the days of a chain
run in order.

A task's ``key`` is a fingerprint of everything its output depends on: ltmap's version, the
effective parameters, its inputs (path relative to the manifest, size and modification time of
every log file and static file) and the key of the task it builds on (the previous day, the
static plan). A day folder whose ``batch_task.json`` holds the same key is up to date.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..config import Config, load_config, set_dotted, to_dict, update_from_dict
from ..errors import ConfigError
from ..io import safe_yaml
from .manifest import Manifest, ManifestError, Site

STATIC_DIR = "static"  # OUT/<site>/static/: the site's plan, built once
DAY_DIR = "day{n}"  # OUT/<site>[/<point>]/day<N>/, N from 1
POINT_NAME_CHARS = re.compile(r"[^A-Za-z0-9._+,=\[\]-]")


@dataclass(frozen=True)
class Point:
    """One point of the parameter sweep: ``name`` is its folder ('' without --sweep)."""

    name: str
    values: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class StaticTask:
    site: str
    plan: Path
    options: dict
    out_dir: Path
    key: str

    @property
    def label(self) -> str:
        return f"{self.site} static plan"


@dataclass(frozen=True)
class DayTask:
    site: str
    point: str
    day: int  # from 1
    logs: tuple[Path, ...]
    out_dir: Path
    static: Path | None
    resume: Path | None
    cfg: Config
    key: str
    weight: int  # bytes of its logs: the unit of the time-left estimate

    @property
    def label(self) -> str:
        return f"{self.site} day {self.day}" + (f" [{self.point}]" if self.point else "")


@dataclass
class Chain:
    site: str
    point: Point
    days: list[DayTask]
    static: StaticTask | None = None


@dataclass
class BatchPlan:
    out: Path
    manifest: Manifest
    points: list[Point]
    statics: dict[str, StaticTask] = field(default_factory=dict)  # site -> its plan build
    chains: list[Chain] = field(default_factory=list)

    def tasks(self) -> list[StaticTask | DayTask]:
        return list(self.statics.values()) + [d for c in self.chains for d in c.days]


# ------------------------------------------------------------------------------------ sweeps
def parse_sweep(spec: str) -> tuple[str, list[tuple[str, Any]]]:
    """``KEY=V1,V2,...`` -> (KEY, [(text, value), ...]); values are YAML (``5``, ``0.1``, ``true``,
    ``[1, 2]``: commas inside brackets do not split)."""
    import yaml

    if "=" not in spec:
        raise ConfigError(
            f"--sweep {spec}: expected KEY=V1,V2,..., e.g. --sweep map.layers.st_rise_s=5,10,15"
        )
    key, raw = (s.strip() for s in spec.split("=", 1))
    texts, depth, cur = [], 0, ""
    for ch in raw:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            texts.append(cur.strip())
            cur = ""
        else:
            cur += ch
    texts.append(cur.strip())
    if not key or any(not t for t in texts):
        raise ConfigError(
            f"--sweep {spec}: a key and non-empty values are needed, e.g. "
            "--sweep map.layers.st_rise_s=5,10,15"
        )
    if len(set(texts)) != len(texts):
        raise ConfigError(f"--sweep {spec}: a value is given twice; give each once")
    values = []
    for t in texts:
        try:
            values.append((t, safe_yaml.loads(t)))
        except (yaml.YAMLError, safe_yaml.YamlLimitError):
            raise ConfigError(f"--sweep {spec}: the value {t!r} is not valid YAML") from None
        try:
            set_dotted(Config(), key, values[-1][1])
        except ConfigError as err:
            raise ConfigError(f"--sweep {spec}: {err}") from None
    return key, values


def sweep_points(specs: list[str] | tuple[str, ...]) -> list[Point]:
    """The cartesian product of the sweeps, in the order given; one unnamed point without any."""
    sweeps = [parse_sweep(s) for s in specs]
    if not sweeps:
        return [Point("")]
    keys = [k for k, _ in sweeps]
    dup = next((k for k in keys if keys.count(k) > 1), None)
    if dup:
        raise ConfigError(f"--sweep {dup} is given twice; give all its values in one --sweep {dup}=V1,V2,...")
    short = {k: k.rsplit(".", 1)[-1] for k in keys}
    names = {k: short[k] if list(short.values()).count(short[k]) == 1 else k for k in keys}
    points, seen = [], set()
    for combo in itertools.product(*(vals for _, vals in sweeps)):
        name = "+".join(f"{names[k]}={text}" for k, (text, _) in zip(keys, combo))
        name = POINT_NAME_CHARS.sub("_", name)
        if name in seen:
            raise ConfigError(
                f"--sweep: two points would share the folder {name}; write the values differently"
            )
        seen.add(name)
        points.append(Point(name, tuple((k, v) for k, (_, v) in zip(keys, combo))))
    return points


# ------------------------------------------------------------------------------------ config
def effective_config(
    manifest: Manifest, site: Site, base_cfg: Config, sets: list[tuple[str, Any]], point: Point
) -> Config:
    """Defaults < --config FILE (``base_cfg``, loaded once) < the manifest's config < the site's
    config < --set < the sweep point."""
    cfg = copy.deepcopy(base_cfg)
    where = f"site {site.name}" + (f", sweep point {point.name}" if point.name else "")
    try:
        update_from_dict(cfg, manifest.config)
        update_from_dict(cfg, site.config)
        for key, value in sets:
            set_dotted(cfg, key, value)
        for key, value in point.values:
            set_dotted(cfg, key, value)
        cfg.validate()
    except ConfigError as err:
        raise ManifestError(f"manifest {manifest.path}: {where}: {err}") from None
    return cfg


# ------------------------------------------------------------------------------------ fingerprints
def _stat(p: Path, base: Path) -> list:
    st = p.stat()
    try:
        shown = os.path.relpath(p, base)
    except ValueError:  # another drive (Windows)
        shown = str(p)
    return [shown, st.st_size, st.st_mtime_ns]


def input_identity(path: Path, base: Path) -> list:
    """Size and modification time of a file, or of every file under a folder (a ROS 2 bag, a
    build-static output), with paths relative to ``base`` (the manifest's folder): moving the
    fleet's folder as a whole keeps the fingerprints."""
    if path.is_dir():
        files = sorted(q for q in path.rglob("*") if q.is_file())
        return [_stat(q, base) for q in files]
    out = [_stat(path, base)]
    if path.suffix.lower() in (".yaml", ".yml"):  # a map YAML: its image too
        out += [_stat(q, base) for q in _map_image(path)]
    return out


def _map_image(yaml_path: Path) -> list[Path]:
    try:  # (a map YAML that cannot be read fails later, in the replay, with its own message)
        doc = safe_yaml.load_file(yaml_path, "map YAML", ValueError)
    except ValueError:
        return []
    image = doc.get("image") if isinstance(doc, dict) else None
    if not isinstance(image, str):
        return []
    p = Path(image) if Path(image).is_absolute() else yaml_path.parent / image
    return [p] if p.is_file() else []


def fingerprint(doc: dict) -> str:
    text = json.dumps({"ltmap": __version__, **doc}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


# ------------------------------------------------------------------------------------ the plan
def day_dir(out: Path, site: str, point: Point, day: int) -> Path:
    base = out / site / point.name if point.name else out / site
    return base / DAY_DIR.format(n=day)


def build_plan(
    manifest: Manifest,
    out: Path,
    *,
    config_file: Path | None = None,
    sets: list[tuple[str, Any]] | None = None,
    sweeps: list[str] | tuple[str, ...] = (),
) -> BatchPlan:
    """Every task of the batch, with its folder and fingerprint (raises ConfigError / ManifestError)."""
    out = out.absolute()
    base = manifest.path.parent.absolute()
    points = sweep_points(sweeps)
    plan = BatchPlan(out=out, manifest=manifest, points=points)
    base_cfg = load_config(config_file)
    for site in manifest.sites:
        static_path, static_key = site.static, None
        if site.static_is_plan:
            st_key = fingerprint(
                {"kind": "static", "plan": input_identity(site.static, base), "options": site.static_options}
            )
            task = StaticTask(
                site.name, site.static, dict(site.static_options), out / site.name / STATIC_DIR, st_key
            )
            plan.statics[site.name] = task
            static_path, static_key = task.out_dir, st_key
        elif site.static is not None:
            static_key = fingerprint({"kind": "static input", "files": input_identity(site.static, base)})
        identities = [[input_identity(p, base) for p in logs] for logs in site.days]
        weights = [sum(size for ident in day for _, size, _ in ident) for day in identities]  # bytes of the day's logs
        for point in points:
            cfg = effective_config(manifest, site, base_cfg, list(sets or []), point)
            settings = to_dict(cfg)
            settings["replay"].pop("workers", None)  # how many threads cast the rays: not the map's
            chain = Chain(site.name, point, [], plan.statics.get(site.name))
            prev_key, prev_dir = None, None
            for i, logs in enumerate(site.days, start=1):
                key = fingerprint(
                    {
                        "kind": "day",
                        "config": settings,
                        "logs": identities[i - 1],
                        "static": static_key,
                        "previous": prev_key,
                    }
                )
                folder = day_dir(out, site.name, point, i)
                chain.days.append(
                    DayTask(
                        site.name,
                        point.name,
                        i,
                        logs,
                        folder,
                        static_path,
                        prev_dir,
                        cfg,
                        key,
                        weights[i - 1],
                    )
                )
                prev_key, prev_dir = key, folder
            plan.chains.append(chain)
    return plan

