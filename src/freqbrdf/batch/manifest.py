"""The manifest of a batch: which captures, under which names, with which settings.

`read_manifest` reads a CSV file (a header row, then a capture a line), a JSON Lines file (an
object a line) or a folder of captures, and checks all of it before any work: each capture
exists, each name is a plain folder name that no other capture has (ignoring case), and each
setting is known and valid (`freqbrdf.batch.settings`). Every problem is an `InputError` naming the
file and the line. Each capture becomes a `ManifestEntry`.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass
from pathlib import Path

from freqbrdf.batch.index import BATCH_FILE, INDEX_FILE
from freqbrdf.batch.settings import SETTINGS, capture_config, parse_settings
from freqbrdf.errors import InputError

MANIFEST_SUFFIXES = {".csv": "csv", ".jsonl": "jsonl", ".ndjson": "jsonl"}
CAPTURE_FILES = ("transforms.json", "transforms_train.json")  # a folder holding one is a capture
MANIFEST_KEYS = ("name", "capture", *SETTINGS)
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_RESERVED_NAMES = {BATCH_FILE, INDEX_FILE}


@dataclass(frozen=True)
class ManifestEntry:
    """One capture of a manifest.

    Attributes
    ----------
    name : str
        The capture's output folder under OUT (letters, digits, ``.``, ``_``, ``-``).
    capture : Path
        The capture's folder or transforms file, absolute.
    settings : dict
        Its settings (`parse_settings`), the batch's defaults filled in.
    where : str
        Where it was given, for messages (``"captures.csv line 3"``).
    """

    name: str
    capture: Path
    settings: dict
    where: str

    @property
    def root(self) -> Path:
        """The capture's folder (the transforms file's folder where a file was given)."""
        return self.capture if self.capture.is_dir() else self.capture.parent


def read_manifest(path: str | Path, defaults: dict | None = None) -> list[ManifestEntry]:
    """Read and check a whole manifest before any work.

    A CSV file has a header row with the columns ``name`` (optional: the capture folder's name),
    ``capture`` (the capture's folder or transforms file, relative to the manifest's folder) and
    any of the settings of `SETTINGS`, empty cells taking the defaults. A JSON Lines file
    (``.jsonl``) holds one object a line with the same keys. A folder stands for its subfolders
    that hold a capture (``transforms.json`` or Stanford-ORB's ``transforms_train.json``), each
    named after its folder. Every problem (unknown key or value, duplicate name, missing capture)
    raises `InputError` naming the file and the line.

    Parameters
    ----------
    path : str or Path
        The manifest file or folder.
    defaults : dict, optional
        Settings for every capture that its own line does not set (`parse_settings`'s keys).

    Returns
    -------
    list of ManifestEntry
        The captures in the manifest's order.
    """
    path = Path(path)
    try:
        defaults = parse_settings(dict(defaults or {}))
    except ValueError as err:
        raise InputError(None, str(err)) from None
    if not path.exists():
        raise InputError(path, "manifest does not exist")
    if path.is_dir():
        rows = _folder_rows(path)
    elif path.suffix.lower() in MANIFEST_SUFFIXES:
        rows = _csv_rows(path) if MANIFEST_SUFFIXES[path.suffix.lower()] == "csv" else _jsonl_rows(path)
    else:
        raise InputError(path, f"manifest must be a .csv or .jsonl file or a folder of captures, "
                               f"not {path.suffix or 'a file without extension'}")
    if not rows:
        raise InputError(path, "manifest lists no capture")
    base = path if path.is_dir() else path.parent
    entries: list[ManifestEntry] = []
    seen: dict[str, int] = {}
    for line, row in rows:
        where = f"line {line}: " if not path.is_dir() else ""
        entry = _entry(path, base, line, row, defaults, where)
        key = entry.name.lower()  # case-insensitive file systems would merge two such folders
        if key in seen:
            raise InputError(path, f"{where}name {entry.name!r} also on line {seen[key]}; names must differ "
                                   "(ignoring case)")
        seen[key] = line
        entries.append(entry)
    return entries


def _entry(path: Path, base: Path, line: int, row: dict, defaults: dict, where: str) -> ManifestEntry:
    unknown = [key for key in row if key not in MANIFEST_KEYS]
    if unknown:
        raise InputError(path, f"{where}unknown key {unknown[0]!r}; keys are {', '.join(MANIFEST_KEYS)}")
    capture_value = row.get("capture")
    if not isinstance(capture_value, str) or not capture_value.strip():
        raise InputError(path, f"{where}capture is missing (a capture folder or transforms file)")
    capture = (base / capture_value.strip()).resolve()
    if not capture.exists():
        raise InputError(path, f"{where}capture {capture_value.strip()!r} does not exist ({capture})")
    if capture.is_dir() and not any((capture / name).is_file() for name in CAPTURE_FILES):
        raise InputError(path, f"{where}capture {capture_value.strip()!r} holds no {' or '.join(CAPTURE_FILES)}")
    name = row.get("name")
    if name in (None, ""):
        name = capture.name if capture.is_dir() else capture.parent.name
    if not isinstance(name, str) or not _NAME.fullmatch(name) or name in _RESERVED_NAMES:
        raise InputError(path, f"{where}name {name!r} must start with a letter or digit and hold only letters, "
                               f"digits, '.', '_' and '-' (and not be {' or '.join(sorted(_RESERVED_NAMES))})")
    try:
        settings = {**defaults, **parse_settings({k: v for k, v in row.items() if k in SETTINGS}, "")}
        capture_config(settings)  # refuses invalid combinations now, not after other captures' work
    except ValueError as err:
        raise InputError(path, f"{where}{err}") from None
    label = path.name if path.is_dir() else f"{path.name} line {line}"
    return ManifestEntry(name, capture, settings, label)


def _csv_rows(path: Path) -> list[tuple[int, dict]]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            if header is None:
                return []
            header = [column.strip() for column in header]
            for column in header:
                if column not in MANIFEST_KEYS:
                    raise InputError(path, f"line 1: unknown column {column!r}; columns are "
                                           f"{', '.join(MANIFEST_KEYS)}")
            if "capture" not in header:
                raise InputError(path, "line 1: the header needs a 'capture' column")
            if len(set(header)) < len(header):
                raise InputError(path, "line 1: a column appears twice")
            rows = []
            for cells in reader:
                if not any(cell.strip() for cell in cells):
                    continue
                if len(cells) > len(header):
                    raise InputError(path, f"line {reader.line_num}: {len(cells)} cells, the header has "
                                           f"{len(header)} columns")
                rows.append((reader.line_num, dict(zip(header, cells))))
            return rows
    except (UnicodeDecodeError, csv.Error) as err:
        raise InputError(path, f"unreadable CSV: {err}") from None


def _jsonl_rows(path: Path) -> list[tuple[int, dict]]:
    rows = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as err:
        raise InputError(path, f"unreadable: {err}") from None
    for number, text in enumerate(lines, start=1):
        if not text.strip():
            continue
        try:
            row = json.loads(text)
        except json.JSONDecodeError as err:
            raise InputError(path, f"line {number}: not JSON ({err.msg})") from None
        if not isinstance(row, dict):
            raise InputError(path, f"line {number}: must be a JSON object")
        rows.append((number, row))
    return rows


def _folder_rows(path: Path) -> list[tuple[int, dict]]:
    if any((path / name).is_file() for name in CAPTURE_FILES):
        raise InputError(path, "is a capture, not a folder of captures: use `freqbrdf fit`, or a manifest "
                               "listing it")
    folders = sorted(child for child in path.iterdir() if child.is_dir() and not child.name.startswith(".")
                     and any((child / name).is_file() for name in CAPTURE_FILES))
    return [(index, {"name": folder.name, "capture": folder.name}) for index, folder in enumerate(folders, 1)]
