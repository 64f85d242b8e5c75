"""Inputs of a batch: which logs (discovery) and how each is analysed (settings, config file).

Kept apart from :mod:`mrftcli.batch.run` (which runs the work) because both are pure file-system and
validation logic that the tests exercise on their own; :mod:`mrftcli.batch.run` re-exports the public names.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import glob as _glob
import hashlib
import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..jsonable import load_toml_text, load_yaml_text
from ..io import require_input
from ..io.layouts import LAYOUT_NAMES
from ..io.logtypes import LOOPS
from ..validate import check_tp

__all__ = ["LogSettings", "ConfigEntry", "BatchConfig", "load_config", "resolve_settings", "discover_logs", "log_mtime",
           "result_path"]

#: File suffixes (lower case) picked up when a folder or a glob is searched. A folder that holds a
#: ``metadata.yaml`` is a ROS 2 bag and counts as one log (it is not searched further).
SUPPORTED_SUFFIXES = (".mcap", ".bag", ".ulg", ".csv", ".bin", ".mat")

# --------------------------------------------------------------------------------------------------
# Settings
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LogSettings:
    """How one log is analysed.

    Attributes
    ----------
    tp : float or None
        Propulsion time constant Tp [s] from a bench test; required before a log can be analysed.
    loops : tuple of str
        Loops to identify in this log (``altitude``, ``roll``, ``pitch``); one summary row each.
    command_topic, output_topic, beta_topic, setpoint_topic : str or None
        ``TOPIC[:FIELD]`` overrides passed to the reader; None lets it auto-detect.
    output_scale, command_scale : float or None
        Factors applied to the loop output (e.g. 0.001 for a log in millimetres) and to the command;
        None = the layout's.
    layout : str or None
        One of :data:`mrftcli.io.LAYOUT_NAMES`; None = recognised from each log's topics.
    controller_rate_hz : float or None
        Rate [Hz] at which the relay decided, when logs record the command more slowly; None = the
        layout's.
    min_cycles : int or None
        Fewest stable cycles for a test to be used (analyze's ``--min-cycles``); None = its default.
    vehicle : str or None
        Vehicle name used to group logs in the fleet report; None -> the log's parent folder name.
    accept_tp : bool
        Keep a Tp the recording rejects (analyze's ``--accept-tp``); else that loop fails with exit
        code 5, naming the Tp the recording fits.
    """

    tp: float | None = None
    loops: tuple[str, ...] = ("altitude",)
    command_topic: str | None = None
    output_topic: str | None = None
    beta_topic: str | None = None
    setpoint_topic: str | None = None
    output_scale: float | None = None
    min_cycles: int | None = None
    vehicle: str | None = None
    command_scale: float | None = None
    layout: str | None = None
    controller_rate_hz: float | None = None
    accept_tp: bool = False

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["loops"] = list(self.loops)
        return d


#: Keys a config entry may set, with the validator for each (value, where) -> value.
_SETTING_KEYS = ("tp", "loop", "command_topic", "output_topic", "beta_topic", "setpoint_topic", "output_scale",
                 "min_cycles", "vehicle", "command_scale", "layout", "controller_rate_hz", "accept_tp")


def _check_tp(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputError(f"{where}: tp must be a positive number of seconds, got {value!r}")
    try:
        return check_tp(value)
    except InputError as err:
        raise InputError(f"{where}: {err}") from None


#: ``loop = "auto"``: every loop whose topics the log holds and whose relay tests are found.
AUTO_LOOP = "auto"


def _check_loops(value: Any, where: str) -> tuple[str, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not items:
        raise InputError(f"{where}: loop must be one of {', '.join(LOOPS)} or a list of them, got {value!r}")
    loops: list[str] = []
    for item in items:
        for part in str(item).split(",") if isinstance(item, str) else [item]:
            part = part.strip() if isinstance(part, str) else part
            if part not in (*LOOPS, AUTO_LOOP):
                raise InputError(f"{where}: loop must be one of {', '.join(LOOPS)} or auto, got {part!r}")
            if part not in loops:
                loops.append(part)
    return tuple(loops)


def _check_str(value: Any, where: str, key: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{where}: {key} must be a non-empty string, got {value!r}")
    return value


def _check_scale(value: Any, where: str, key: str = "output_scale") -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value == 0:
        raise InputError(f"{where}: {key} must be a finite non-zero number, got {value!r}")
    return float(value)


def _validate_entry(raw: Any, where: str, *, needs_match: bool) -> tuple[str | None, dict[str, Any]]:
    """Check one config table; return (match pattern, settings overrides as LogSettings fields)."""
    if not isinstance(raw, Mapping):
        raise InputError(f"{where}: expected a table of settings, got {type(raw).__name__}")
    known = set(_SETTING_KEYS) | ({"match"} if needs_match else set())
    for key in raw:
        if key not in known:
            raise InputError(f"{where}: unknown key {key!r} (known keys: {', '.join(sorted(known))})")
    pattern = None
    if needs_match:
        if "match" not in raw:
            raise InputError(f"{where}: missing key 'match' (a glob such as \"vehicle7/*.mcap\")")
        pattern = _check_str(raw["match"], where, "match")
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key == "match":
            continue
        if key == "tp":
            out["tp"] = _check_tp(value, where)
        elif key == "loop":
            out["loops"] = _check_loops(value, where)
        elif key in ("output_scale", "command_scale"):
            out[key] = _check_scale(value, where, key)
        elif key == "layout":
            if value not in LAYOUT_NAMES:
                raise InputError(f"{where}: layout must be one of {', '.join(LAYOUT_NAMES)}, got {value!r}")
            out["layout"] = value
        elif key == "controller_rate_hz":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value <= 0:
                raise InputError(f"{where}: controller_rate_hz must be a positive rate in Hz, got {value!r}")
            out[key] = float(value)
        elif key == "accept_tp":
            if not isinstance(value, bool):
                raise InputError(f"{where}: accept_tp must be true or false, got {value!r}")
            out[key] = value
        elif key == "min_cycles":
            if isinstance(value, bool) or not isinstance(value, int) or value < 2:
                raise InputError(f"{where}: min_cycles must be an integer of at least 2, got {value!r}")
            out["min_cycles"] = value
        else:
            out[key] = _check_str(value, where, key)
    return pattern, out


@dataclass(frozen=True)
class ConfigEntry:
    """One ``[[logs]]`` entry: a glob and the settings it sets."""

    match: str
    overrides: Mapping[str, Any]
    index: int


@dataclass(frozen=True)
class BatchConfig:
    """A parsed per-log settings file (see ``docs/batch.md``).

    Precedence, lowest first: built-in defaults, then ``[defaults]``, then every ``[[logs]]`` entry
    whose ``match`` glob matches the log *in file order, a later match overriding an earlier one*, then
    options given explicitly on the command line.
    """

    path: Path | None = None
    defaults: Mapping[str, Any] = field(default_factory=dict)
    entries: tuple[ConfigEntry, ...] = ()

    def matching(self, log: Path) -> list[ConfigEntry]:
        """The entries whose glob matches ``log``, in file order."""
        return [e for e in self.entries if _glob_matches(e.match, log, self.base)]

    @property
    def base(self) -> Path:
        return self.path.parent.resolve() if self.path is not None else Path.cwd()


def _glob_matches(pattern: str, log: Path, base: Path) -> bool:
    """Whether a config glob matches a log.

    A pattern without ``/`` matches the log's file (or bag folder) name. A pattern with ``/`` matches
    the log's path relative to the config file's folder, or its absolute path. ``*`` also crosses
    ``/`` (fnmatch semantics) and a leading ``**/`` may match nothing.
    """
    log = log.resolve()
    candidates: list[str]
    if "/" not in pattern:
        candidates = [log.name]
    else:
        candidates = [log.as_posix()] + ([log.relative_to(base).as_posix()] if log.is_relative_to(base) else [])
    patterns = [pattern]
    if pattern.startswith("**/"):
        patterns.append(pattern[3:])
    return any(fnmatch.fnmatchcase(c, p) for c in candidates for p in patterns)


def load_config(path: str | os.PathLike[str]) -> BatchConfig:
    """Read and validate a per-log settings file (TOML, or YAML for ``.yaml``/``.yml``).

    Raises
    ------
    InputError
        The file is missing, does not parse, or has an unknown key or a bad value; the message names
        the file and the key.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise InputError(f"cannot read config file {p}: {err.strerror or err}") from err
    if p.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml  # noqa: F401  # PyYAML, only needed for YAML configs
        except ImportError as err:  # pragma: no cover - depends on the environment
            raise InputError(f"{p}: YAML configs need PyYAML (pip install pyyaml), or use TOML") from err
        # the safe loader, its aliases' expansion and its depth bounded (a 341-byte file can expand to 10**9)
        raw = load_yaml_text(text, str(p))
        raw = {} if raw is None else raw
    else:
        raw = load_toml_text(text, str(p))
    if not isinstance(raw, Mapping):
        raise InputError(f"{p}: expected a mapping with [defaults] and [[logs]], got {type(raw).__name__}")
    for key in raw:
        if key not in ("defaults", "logs"):
            raise InputError(f"{p}: unknown top-level key {key!r} (expected 'defaults' and 'logs')")
    _, defaults = _validate_entry(raw.get("defaults", {}), f"{p}: [defaults]", needs_match=False)
    logs = raw.get("logs", [])
    if not isinstance(logs, list):
        raise InputError(f"{p}: 'logs' must be an array of tables ([[logs]] entries)")
    entries = []
    for i, item in enumerate(logs):
        pattern, overrides = _validate_entry(item, f"{p}: logs[{i}]", needs_match=True)
        assert pattern is not None
        entries.append(ConfigEntry(pattern, overrides, i))
    return BatchConfig(p, defaults, tuple(entries))


def resolve_settings(
    log: Path, base: Mapping[str, Any], config: BatchConfig | None, explicit: Mapping[str, Any]
) -> tuple[LogSettings, list[int]]:
    """Settings for one log: ``base`` < config defaults < matching entries < ``explicit``.

    Returns the settings and the indices of the config entries that matched.
    """
    values: dict[str, Any] = dict(base)
    matched: list[int] = []
    if config is not None:
        values.update(config.defaults)
        for entry in config.matching(log):
            values.update(entry.overrides)
            matched.append(entry.index)
    values.update(explicit)
    return LogSettings(**values), matched


# --------------------------------------------------------------------------------------------------
# Discovery
# --------------------------------------------------------------------------------------------------


def _is_ros2_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def _is_supported_file(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in SUPPORTED_SUFFIXES


def _walk(folder: Path, exclude: Sequence[Path]) -> Iterator[Path]:
    """Logs below ``folder``: supported files and ROS 2 bag folders (not descended into)."""
    for root, dirs, files in os.walk(folder):
        root_p = Path(root)
        keep = []
        for d in sorted(dirs):
            sub = root_p / d
            if d.startswith(".") or any(sub.resolve().is_relative_to(ex) for ex in exclude):
                continue
            if _is_ros2_bag(sub):
                yield sub
            else:
                keep.append(d)
        dirs[:] = keep  # os.walk descends only into these
        for f in sorted(files):
            fp = root_p / f
            if not f.startswith(".") and _is_supported_file(fp):
                yield fp


def discover_logs(paths: Iterable[str | os.PathLike[str]], exclude: Sequence[str | os.PathLike[str]] = ()) -> list[Path]:
    """Expand files, folders and globs into a sorted, de-duplicated list of logs.

    * a file is taken as given, whatever its suffix (the reader decides whether it can read it);
    * a folder is searched recursively for files with a suffix in :data:`SUPPORTED_SUFFIXES`
      (case-insensitive) and for ROS 2 bag folders (a folder holding ``metadata.yaml``), each of which is
      one log and is not searched further; hidden entries and the ``exclude`` folders (the output
      folder) are skipped;
    * a path that does not exist but contains ``*``, ``?`` or ``[`` is a glob (``**`` recurses); its
      matches are treated like the above, except that matched files must have a supported suffix.

    Raises
    ------
    InputError
        A glob matches nothing, or nothing loggable was found at all.
    LogReadError
        A path that is no glob does not exist (:func:`mrftcli.io.require_input`).
    """
    excl = [Path(e).resolve() for e in exclude]
    found: dict[Path, None] = {}
    given = [str(p) for p in paths]
    if not given:
        raise InputError("no log paths given: pass files, folders or globs")

    def add_path(p: Path, from_glob: bool) -> None:
        if from_glob and any(p.resolve().is_relative_to(ex) for ex in excl):
            return
        if _is_ros2_bag(p):
            found[p.resolve()] = None
        elif p.is_dir():
            for log in _walk(p, excl):
                found[log.resolve()] = None
        elif p.is_file():
            if not from_glob or _is_supported_file(p):
                found[p.resolve()] = None

    for arg in given:
        p = Path(arg).expanduser()
        if p.exists():
            add_path(p, from_glob=False)
        elif any(ch in arg for ch in "*?["):
            matches = sorted(_glob.glob(str(p), recursive=True))
            if not matches:
                raise InputError(f"the pattern {arg!r} matches no files")
            for m in matches:
                add_path(Path(m), from_glob=True)
        else:
            require_input(p)  # raises: the one missing-input error (exit 3)
    if not found:
        raise InputError(
            f"no logs found in {', '.join(given)} (looked for {', '.join(SUPPORTED_SUFFIXES)} files and "
            "ROS 2 bag folders with metadata.yaml)"
        )
    return sorted(found)


def log_mtime(path: Path) -> float:
    """Modification time [s since the epoch]; a ROS 2 bag folder's is the newest file inside it."""
    if path.is_dir():
        times = [path.stat().st_mtime]
        for root, _, files in os.walk(path):
            times.extend((Path(root) / f).stat().st_mtime for f in files)
        return max(times)
    return path.stat().st_mtime


def result_path(out_dir: Path, log: Path) -> Path:
    """Where a log's record goes: its name plus 8 hex digits of its absolute path, so names never collide."""
    digest = hashlib.sha256(str(log.resolve()).encode()).hexdigest()[:8]
    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in log.name) or "log"
    return out_dir / "logs" / f"{safe}.{digest}.json"
