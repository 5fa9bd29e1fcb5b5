"""The results store: one folder per evaluation run, its provenance in a manifest and its episodes as JSON Lines.

    <root>/runs/<run>/manifest.json   what the run plays with: role, playouts, episode seeds, log checksums, each
                                      world model's weights (SHA-256) and caution, every command that ran it
    <root>/runs/<run>/episodes.jsonl  one JSON object per played episode, appended as each finishes

JSON Lines rather than Parquet: a row is appended, whole, the moment its episode finishes (a Parquet file cannot be
appended to), so an interrupted run loses at most the episode being written; and a run reads with nothing but a
JSON parser (`pandas.read_json(path, lines=True)`, duckdb's `read_json_auto`). Appends take an exclusive lock on
`episodes.lock` and write one line with one `write`; a torn last line (a writer killed mid-line) is reported and
cut off by the next append, and its episode is played again. A row counts for its run only while its provenance
equals the manifest's; rows played under an earlier manifest stay in the file, stale, and are not counted.

Both files have a schema (`dynplan.evaluation.store_schema`), checked on every read and before every write: a
manifest or row of the wrong types, out of range or missing a field is a StoreError naming the file and the line,
never a row that silently stops counting. A case played twice with the same provenance is refused naming both
lines when the two rows differ (the table would otherwise count whichever came last); a line repeated exactly is
read once.

Every world's runs have this layout and these guarantees; what a run's manifest and rows hold is its world's
(`RunKind`: the schemas, the keys of a case and of its provenance, and what the manifest asks of each row). A
manifest names its world (`world`: its versioned id, `<name>-v<N>`); one without that field is the road's, whose
`RunKind` is `ROAD_RUNS`. Each world keeps its runs under a root of its own (the road's `datasets/results`,
another world's `datasets/results/<world>`).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import threading
import warnings
from collections.abc import Iterable, Mapping
from contextlib import AbstractContextManager
from datetime import datetime, timezone
from pathlib import Path

from dynplan.cli import InputError
from dynplan.evaluation.store_schema import FORMAT, ROLES, ManifestSchema, RowSchema, first_problem, line_of
from dynplan.files import exclusive, is_held, write_bytes_atomic
from dynplan.models.caution import Caution
from dynplan.version import __version__
from dynplan.world import DEFAULT_WORLD, world, world_names
from dynplan.world_parts import RunKind

#: Table 1's run.
EVALUATION_RUN = "evaluation"
#: What identifies an episode within a run.
CASE_KEYS = ("technique", "model", "agent_speed", "rollout_steps", "seed")
#: What a result depends on besides its case (a caution setting is recorded only while it is on).
PROVENANCE_KEYS = ("playouts", "log_sha256", "world_model_sha256", *Caution.model_fields)
#: What a row records of how its episode went; every other key of a row is its case or its provenance.
RESULT_KEYS = ("outcome", "steps", "decision_ms", "wall_s", "code_version")
_RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")
_RUN_RULE = "letters, digits, '_', '.', '-' (up to 100, not starting with a punctuation mark)"


class StoreError(InputError):
    """A run's files are unreadable or inconsistent; the message names the file and what is wrong."""


def shown(path: str | os.PathLike) -> str:
    """A path as a message names it: relative to the working folder when inside it (as the user typed it)."""
    path = Path(path)
    try:
        return str(path.absolute().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


class TornRowWarning(UserWarning):
    """A run's last line was cut off mid-write (its writer was killed); that episode is played again."""


def code_version() -> str:
    """The package version and, in a git checkout, the commit (with `-dirty` when tracked files changed)."""
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=12"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"dynplan {__version__}" + (f" ({commit})" if commit else "")


def case_key(row: Mapping) -> tuple:
    """A road row's case (`CASE_KEYS`)."""
    return tuple(row.get(k) for k in CASE_KEYS)


def provenance_of(row: Mapping) -> dict:
    """The provenance a road row records: `PROVENANCE_KEYS` (None where absent: a caution setting that is off) and
    any other key that is neither its case nor its result (`RunKind.provenance_of`)."""
    return ROAD_RUNS.provenance_of(row)


def check_run_name(name: str) -> str:
    if not isinstance(name, str) or not _RUN_NAME.fullmatch(name):
        raise StoreError(f"run name {name!r} is invalid: {_RUN_RULE}")
    return name


def run_argument(value: str) -> str:
    """An argparse `type` for a `--run` option: a valid run name (`check_run_name`), refused naming the option."""
    try:
        return check_run_name(value)
    except StoreError:
        raise argparse.ArgumentTypeError(f"{value!r} is not a run name: {_RUN_RULE}") from None


class Run:
    """One named run of a results store rooted at `root` (e.g. `datasets/results`); `kind`: what a new run holds
    (default the road's; an existing run's is its manifest's world's)."""

    def __init__(self, root: str | os.PathLike, name: str = EVALUATION_RUN, kind: RunKind | None = None) -> None:
        self.root = Path(root)
        self.name = check_run_name(name)
        self._kind, self._manifests_kind = kind, None
        self.dir = self.root / "runs" / name
        self.manifest_path = self.dir / "manifest.json"
        self.episodes_path = self.dir / "episodes.jsonl"
        self._lock_path = self.dir / "episodes.lock"

    def __repr__(self) -> str:
        return f"Run({str(self.root)!r}, {self.name!r})"

    def exists(self) -> bool:
        return self.manifest_path.is_file()

    @property
    def kind(self) -> RunKind:
        """What the run holds: its manifest's world's kind (read once: a run's world never changes), or (no manifest
        yet) the one it was made with."""
        if self._manifests_kind is None:
            if not self.exists():
                return self._kind or ROAD_RUNS
            self._manifests_kind = kind_of(_world_field(self.manifest_path), self.manifest_path)
        return self._manifests_kind

    # -- manifest ---------------------------------------------------------------------------------------------
    def manifest(self) -> dict:
        """The run's manifest, checked against its schema and its folder's name (StoreError naming the file and
        line when it is missing, damaged or invalid)."""
        path = shown(self.manifest_path)
        try:
            text = self.manifest_path.read_text()
            manifest = json.loads(text)
        except FileNotFoundError:
            raise StoreError(f"{path}: no such manifest (run {self.name!r} never started)") from None
        except UnicodeDecodeError as error:
            raise StoreError(f"{path}: not a JSON manifest (not UTF-8 text: {error.reason})") from None
        except json.JSONDecodeError as error:
            where = f"{path}:{error.lineno}"
            raise StoreError(f"{where}: not a JSON manifest ({error.msg}, column {error.colno})") from None
        except RecursionError:
            raise StoreError(f"{path}: not a manifest (nested too deeply to read)") from None
        except OSError as error:
            raise StoreError(f"{path}: cannot be read ({error.strerror})") from None
        found = manifest.get("format") if isinstance(manifest, dict) else None
        if found != FORMAT:
            raise StoreError(f"{path}: not a {FORMAT} manifest (format {found!r})")
        kind = kind_of(manifest.get("world"), self.manifest_path)
        if self._kind is not None and kind.world != self._kind.world:
            raise StoreError(
                f"{path}: run {self.name!r} holds {kind.world} episodes, not {self._kind.world}'s; name "
                "another run with --run"
            )
        problem = first_problem(kind.manifest_schema, manifest)
        if problem is not None:
            raise StoreError(f"{path}:{line_of(text, problem[0])}: {problem[1]}")
        if manifest["name"] != self.name:
            raise StoreError(
                f"{path}:{line_of(text, ('name',))}: field 'name' = {manifest['name']!r} is not its "
                f"run's folder name {self.name!r}"
            )
        return manifest

    def write_manifest(self, manifest: Mapping) -> None:
        """Write the manifest, atomically; one its schema refuses is a StoreError and is not written."""
        if manifest.get("role") not in ROLES:
            raise StoreError(f"run {self.name!r}: role {manifest.get('role')!r} is invalid; one of {ROLES}")
        problem = first_problem(kind_of(manifest.get("world")).manifest_schema, dict(manifest))
        if problem is not None:
            raise StoreError(f"{shown(self.manifest_path)}: the manifest to write is invalid: {problem[1]}")
        write_bytes_atomic(self.manifest_path, (json.dumps(manifest, indent=1) + "\n").encode())

    def begin(
        self,
        role: str,
        playouts: int,
        seeds: Iterable[int],
        log_sha256: Mapping[int, str | None],
        world_models: Mapping[str, Mapping],
        command: str,
    ) -> dict:
        """Create the run, or extend its manifest with what this invocation plays: more seeds and logs, a world
        model, or new weights / caution for one (whose earlier rows then go stale). A run's role and playouts do
        not change (another value is refused). Returns the manifest written."""
        if role not in ROLES:
            raise StoreError(f"run {self.name!r}: role {role!r} is invalid; one of {ROLES}")
        with self._locked():  # two invocations extending one run keep both's seeds and models
            return self._begin(role, playouts, seeds, log_sha256, world_models, command)

    def _begin(self, role, playouts, seeds, log_sha256, world_models, command) -> dict:
        if self.exists():
            manifest = self.manifest()
            if manifest["role"] != role:
                raise StoreError(
                    f"{self.manifest_path}: run {self.name!r} has role {manifest['role']}; this "
                    f"invocation plays a {role} run: name another run with --run"
                )
        else:
            manifest = {
                "format": FORMAT,
                "name": self.name,
                "role": role,
                "playouts": playouts,
                "episode_seeds": [],
                "log_sha256": {},
                "world_models": {},
                "invocations": [],
            }
        if manifest["playouts"] != playouts:
            raise StoreError(
                f"{self.manifest_path}: run {self.name!r} plays {manifest['playouts']} playouts per "
                f"decision, not {playouts}: name another run with --run"
            )
        manifest["episode_seeds"] = sorted(set(manifest["episode_seeds"]) | set(seeds))
        manifest["log_sha256"] = {**manifest["log_sha256"], **{str(s): h for s, h in log_sha256.items()}}
        manifest["world_models"] = {**manifest["world_models"], **{m: dict(v) for m, v in world_models.items()}}
        started = datetime.now(timezone.utc).isoformat(timespec="seconds")
        manifest["invocations"].append({"command": command, "code_version": code_version(), "started": started})
        self.write_manifest(manifest)
        return manifest

    def start(self, role: str, settings: Mapping, world_models: Mapping[str, Mapping], command: str) -> dict:
        """Create the run of a world whose runs name it (`RunKind.world`), or extend its manifest with this
        invocation and the weights it plays with (a world model's new weights make its earlier rows stale). A run's
        role and settings (what every row depends on: an emulator's options, say) do not change: another value is
        refused. Returns the manifest written."""
        if role not in ROLES:
            raise StoreError(f"run {self.name!r}: role {role!r} is invalid; one of {ROLES}")
        kind = self._kind or self.kind
        with self._locked():
            manifest = self.manifest() if self.exists() else self._new_manifest(role, kind, settings)
            for field, value in (("role", role), ("settings", dict(settings))):
                if manifest[field] != value:
                    where = f"{shown(self.manifest_path)}: run {self.name!r}"
                    raise StoreError(f"{where} has {field} {manifest[field]!r}, not {value!r}: name another run")
            manifest["world_models"] = {**manifest["world_models"], **{m: dict(v) for m, v in world_models.items()}}
            started = datetime.now(timezone.utc).isoformat(timespec="seconds")
            manifest["invocations"].append({"command": command, "code_version": code_version(), "started": started})
            self.write_manifest(manifest)
        return manifest

    def _new_manifest(self, role: str, kind: RunKind, settings: Mapping) -> dict:
        fields = {"role": role, "world": kind.world, "settings": dict(settings), "world_models": {}, "invocations": []}
        return {"format": FORMAT, "name": self.name, **fields}

    # -- rows ---------------------------------------------------------------------------------------------------
    def _locked(self) -> AbstractContextManager[None]:
        """Exclusive against other processes and this process's threads."""
        return exclusive(self._lock_path)

    def rows(self) -> list[dict]:
        """Every row of the run's file, in the order written (stale ones included; a line repeated exactly, once).
        An unfinished last line is left out, and reported (TornRowWarning) unless a writer is at work on it; a
        damaged or invalid line, or a second row of a case and provenance that differs from the first, is a
        StoreError naming the file and line(s)."""
        return [row for _, row in self._numbered_rows()]

    def _numbered_rows(self) -> list[tuple[int, dict]]:
        """`rows`, each with its line number."""
        try:
            data = self.episodes_path.read_bytes()
        except FileNotFoundError:
            return []
        except OSError as error:
            raise StoreError(f"{shown(self.episodes_path)}: cannot be read ({error.strerror})") from None
        if data and not data.endswith(b"\n") and is_held(self._lock_path):
            data = data[: data.rfind(b"\n") + 1]  # another writer's row, still being written
        kind = self.kind
        return _merge({}, _parse(data, self.episodes_path, kind), self.episodes_path, kind)

    def append(self, row: Mapping) -> bool:
        """Append one episode's row, unless the run already holds that case with the same provenance (then return
        False): concurrent writers never duplicate a row. A torn last line is cut off first; a row its schema
        refuses is a StoreError and is not written."""
        kind = self.kind
        problem = first_problem(kind.row_schema, dict(row))
        if problem is not None:
            raise StoreError(f"{shown(self.episodes_path)}: the row to append is invalid: {problem[1]}")
        line = (json.dumps(dict(row), separators=(",", ":")) + "\n").encode()
        identity = kind.identity(row)
        with self._locked(), _INDEX_LOCK, open(self.episodes_path, "a+b") as f:
            index = _index(f, self.episodes_path, kind, truncate=True)
            if identity in index:
                return False
            f.write(line)  # "a" mode: at the end, whatever the position
            f.flush()
            os.fsync(f.fileno())
            identity_of_file, offset, lines, _ = _INDEX[self.episodes_path.resolve()]
            index[identity] = (lines + 1, json.loads(line))
            _INDEX[self.episodes_path.resolve()] = (identity_of_file, offset + len(line), lines + 1, index)
        return True

    def find(self, case: Mapping, provenance: Mapping) -> dict | None:
        """The row of `case` played with `provenance`, if the run holds one."""
        kind = self.kind
        try:
            with _INDEX_LOCK, open(self.episodes_path, "rb") as f:
                found = _index(f, self.episodes_path, kind).get(kind.identity({**case, **provenance}))
        except FileNotFoundError:
            return None
        return None if found is None else found[1]

    def expected(self, row: Mapping, manifest: Mapping | None = None) -> dict:
        """The provenance the manifest asks of `row`'s case."""
        manifest = self.manifest() if manifest is None else manifest
        return self.kind.expected(manifest, row)

    def current(self, manifest: Mapping | None = None) -> list[dict]:
        """The rows that count: for each case, the last row whose provenance equals the manifest's. A row the
        manifest contradicts (`RunKind.conflict`: a seed it does not list, other playouts) is a StoreError naming
        the file, the line and the field: such a row was not written by this run and would vanish silently."""
        return [row for _, row in self.counted(manifest)]

    def counted(self, manifest: Mapping | None = None) -> list[tuple[int, dict]]:
        """`current`'s rows, each with its line in the episodes file (what a message about one names)."""
        return [(number, row) for number, row, reason in self._counted(manifest) if reason is None]

    def place(self, number: int) -> str:
        """Where line `number` of the run's episodes is, as a message names it: `FILE:LINE`."""
        return f"{shown(self.episodes_path)}:{number}"

    def stale(self, manifest: Mapping | None = None) -> list[tuple[int, str]]:
        """The rows kept but not counted, each as its line and why (the first provenance field that differs from
        what the manifest asks: weights since replaced, a log recorded again, a setting no longer on)."""
        return [(number, reason) for number, _, reason in self._counted(manifest) if reason is not None]

    def _counted(self, manifest: Mapping | None) -> list[tuple[int, dict, str | None]]:
        """Each row with its line and None where its provenance is the manifest's, else how it differs; for each
        case only the last row that counts is kept."""
        given, manifest = manifest, self.manifest() if manifest is None else manifest
        kind, out, counted = self.kind, [], {}
        for number, row in self._numbered_rows():
            problem = kind.conflict(manifest, row)
            if problem is not None and given is not None:  # a manifest read earlier: another writer may have added
                manifest = self.manifest()
                problem = kind.conflict(manifest, row)
            if problem is not None:
                raise StoreError(
                    f"{self.place(number)}: {problem} ({shown(self.manifest_path)}); restore the manifest or move "
                    "the row to its own run"
                )
            reason = _difference(kind.provenance_of(row), kind.expected(manifest, row))
            if reason is None:
                counted[kind.case_key(row)] = len(out)
            out.append((number, row, reason))
        return [entry for i, entry in enumerate(out) if entry[2] is not None or counted[kind.case_key(entry[1])] == i]


def _difference(recorded: Mapping, expected: Mapping) -> str | None:
    """None where a row's provenance is what its manifest asks; else the first field that differs, in words."""
    for key in sorted(recorded.keys() | expected.keys()):
        if recorded.get(key) != expected.get(key):
            return f"{key} {_short(recorded.get(key))}, the manifest asks {_short(expected.get(key))}"
    return None


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 24 else text[:23] + "…"


def expected_provenance(manifest: Mapping, case: Mapping) -> dict:
    """The provenance a manifest asks of one case (technique, model, speed, k, seed)."""
    out = {k: None for k in PROVENANCE_KEYS}
    out["playouts"] = manifest["playouts"]
    out["log_sha256"] = manifest["log_sha256"].get(str(case["seed"]))
    model = case.get("model")
    if model is not None:
        entry = manifest["world_models"].get(model, {})
        out["world_model_sha256"] = entry.get("weights_sha256")
        out.update(entry.get("caution", {}))
    return out


def expected_weights(manifest: Mapping, case: Mapping) -> dict:
    """What a manifest asks of a row's provenance in a world whose rows record only their world model's weights
    (a `RunKind.expected` a world's runs may use): the SHA-256 it records of the case's model, None for a
    row without one."""
    model = case.get("model")
    return {"world_model_sha256": manifest["world_models"].get(model, {}).get("weights_sha256") if model else None}


def _road_conflict(manifest: Mapping, row: Mapping) -> str | None:
    """What in a road row its manifest contradicts: a seed the run never listed, or other playouts (a run's playouts
    never change)."""
    if row.get("seed") not in manifest["episode_seeds"]:
        return f"field 'seed' = {row.get('seed')!r} is not one of the run's episode seeds"
    if row.get("playouts") != manifest["playouts"]:
        return f"field 'playouts' = {row.get('playouts')!r} is not the run's {manifest['playouts']} playouts"
    return None


#: The road's runs: Table 1's cases (technique, world model, speed, k, seed) with their playouts, logs and weights.
ROAD_RUNS = RunKind(
    f"{DEFAULT_WORLD}-v1",
    ManifestSchema,
    RowSchema,
    CASE_KEYS,
    PROVENANCE_KEYS,
    RESULT_KEYS,
    expected_provenance,
    _road_conflict,
)


def _world_field(path: Path) -> str | None:
    """The `world` a manifest names (None: none, or not a readable manifest, which `Run.manifest` names)."""
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    return manifest.get("world") if isinstance(manifest, dict) and isinstance(manifest.get("world"), str) else None


def kind_of(world_id: str | None, path: str | os.PathLike | None = None) -> RunKind:
    """The kind of a run whose manifest names world `world_id` (None: the road's); a StoreError naming the
    manifest when no registered world of that version keeps runs."""
    if world_id is None or world_id == ROAD_RUNS.world:
        return ROAD_RUNS
    name, _, version = world_id.rpartition("-v")
    where = f"{shown(path)}: " if path is not None else ""
    if name not in world_names() or str(world(name).version) != version:
        raise StoreError(f"{where}field 'world' = {world_id!r} is not a registered world's id (name-vN)")
    kind = world(name).load().runs
    if kind is None or kind.world != world_id:
        raise StoreError(f"{where}the {name} world keeps no runs of {world_id!r}")
    return kind


def _parse(data: bytes, path: Path, kind: RunKind, first_line: int = 1) -> list[tuple[int, dict]]:
    """The rows of `data` (lines of `path` from `first_line` on) with their line numbers, each checked against
    the schema. A last line without its newline was never finished: reported and left out, whatever it holds."""
    lines = data.split(b"\n")
    rows = []
    for i, line in enumerate(lines):
        number = first_line + i
        if not line.strip():
            continue
        last = i == len(lines) - 1  # no newline after it: it was never finished
        try:
            row = json.loads(line)
            if not isinstance(row, dict):
                raise ValueError("not a JSON object")
        except (ValueError, RecursionError) as error:  # UnicodeDecodeError is a ValueError
            if last:
                warnings.warn(
                    f"{shown(path)}: line {number} is torn (a writer stopped mid-row; {len(line)} bytes, "
                    f"{error}); its episode will be played again",
                    TornRowWarning,
                    stacklevel=3,
                )
                continue
            raise StoreError(f"{shown(path)}:{number}: not a JSON row ({error}); the file is damaged") from None
        if last:
            warnings.warn(
                f"{shown(path)}: line {number} has no newline (a writer stopped before finishing it); its "
                f"episode will be played again",
                TornRowWarning,
                stacklevel=3,
            )
            continue
        problem = first_problem(kind.row_schema, row)
        if problem is not None:
            raise StoreError(f"{shown(path)}:{number}: {problem[1]}")
        rows.append((number, row))
    return rows


def _merge(
    seen: dict[str, tuple[int, dict]], rows: list[tuple[int, dict]], path: Path, kind: RunKind
) -> list[tuple[int, dict]]:
    """Add `rows` (line, row) to `seen` (identity → line, row) and return those added: a line repeated exactly is
    read once; another row of a case and provenance already seen is a StoreError naming both lines (which one
    counts would otherwise depend on their order)."""
    added = []
    for number, row in rows:
        identity = kind.identity(row)
        first = seen.get(identity)
        if first is None:
            seen[identity] = (number, row)
            added.append((number, row))
        elif first[1] != row:
            other = first[1]
            fields = sorted(k for k in other.keys() | row.keys() if other.get(k) != row.get(k))
            differ = ", ".join(
                k if isinstance(row.get(k), list) else f"{k} {other.get(k)!r} vs {row.get(k)!r}" for k in fields
            )
            case = " ".join(f"{k}={v!r}" for k, v in zip(kind.case_keys, kind.case_key(row), strict=True))
            raise StoreError(
                f"{shown(path)}:{number}: case {case} has another result with the same provenance "
                f"at line {first[0]} ({differ}); keep one of the two lines"
            )
    return added


def runs(root: str | os.PathLike, role: str | None = None) -> list[Run]:
    """The runs of a store (with role `role`, if given), by name. A run folder whose episodes have no manifest
    beside them is a StoreError: its rows would vanish from every table without a word."""
    _check_readable(Path(root) / "runs")
    for orphan in sorted(Path(root).glob("runs/*/episodes.jsonl")):
        if not (orphan.parent / "manifest.json").is_file():
            raise StoreError(
                f"{shown(orphan)}: its run has episodes and no manifest.json; restore the manifest or "
                f"move the folder out of {shown(Path(root) / 'runs')}"
            )
    found = []
    for path in sorted(Path(root).glob("runs/*/manifest.json")):
        try:
            found.append(Run(root, path.parent.name))
        except StoreError as error:
            raise StoreError(f"{shown(path.parent)}: {error}") from None
    return [r for r in found if role is None or r.manifest()["role"] == role]


def _check_readable(folder: Path) -> None:
    """A StoreError naming the first run folder (or `folder` itself) that cannot be listed or read: its rows would
    otherwise be left out of every table without a word."""
    if not folder.is_dir():
        return
    _check_listable(folder)  # before listing it: a folder that cannot be listed is named, not an OSError
    for path in sorted(p for p in folder.iterdir() if p.is_dir()):
        _check_listable(path)


def _check_listable(path: Path) -> None:
    if not os.access(path, os.R_OK | os.X_OK):
        raise StoreError(
            f"{shown(path)}: cannot be read (permission denied); what it holds would be left out of every table"
        )


def check_store(root: str | os.PathLike) -> None:
    """Read every run of the store at `root` through its schema and its manifest (a StoreError naming the file and
    line otherwise): what a command that reads or extends the store can call before any work starts."""
    for run in runs(root):
        run.current()  # the manifest, every row, and each row against the manifest


def stale_report(root: str | os.PathLike) -> list[str]:
    """A line for each run of the store at `root`, and of each world's store under it (`<root>/<world>`), that
    keeps rows it does not count: how many, and the first one's line and how its provenance differs."""
    lines = []
    for store in (Path(root), *sorted(p.parent for p in Path(root).glob("*/runs"))):
        for run in runs(store):
            stale = run.stale()
            if stale:
                (number, reason), n = stale[0], len(stale)
                lines.append(
                    f"{shown(run.episodes_path)}: {n} row{'s' if n > 1 else ''} kept but not counted (played with "
                    f"other provenance than the manifest asks); the first, line {number}: {reason}"
                )
    return lines


def evaluation_rows(root: str | os.PathLike) -> list[dict]:
    """The rows Table 1 counts: the current rows of every evaluation run. A case in two evaluation runs is refused,
    naming both."""
    seen: dict[tuple, str] = {}
    out = []
    for run in runs(root, "evaluation"):
        for row in run.current():
            key = case_key(row)
            if key in seen:
                raise StoreError(
                    f"{root}: episode {dict(zip(CASE_KEYS, key, strict=True))} is in two evaluation runs, "
                    f"{seen[key]!r} and {run.name!r}; mark one as another role"
                )
            seen[key] = run.name
            out.append(row)
    return out


#: episodes file → ((device, inode), bytes read, lines read, its (line, row) by identity): a process reads only what
#: others added since, and starts over when the file was replaced.
_INDEX: dict[Path, tuple[tuple[int, int], int, int, dict[str, tuple[int, dict]]]] = {}
#: Guards `_INDEX` between this process's threads.
_INDEX_LOCK = threading.Lock()


def _index(f, path: Path, kind: RunKind, truncate: bool = False) -> dict[str, tuple[int, dict]]:
    """The rows of the open file `f` by identity (read incrementally); with `truncate` (under the lock), a torn
    last line is cut off."""
    key = path.resolve()
    stat = os.fstat(f.fileno())
    identity = (stat.st_dev, stat.st_ino)
    known, offset, lines, index = _INDEX.get(key, (identity, 0, 0, {}))
    size = f.seek(0, os.SEEK_END)
    if known != identity or size < offset:  # replaced or rewritten by someone else: start over
        offset, lines, index = 0, 0, {}
    f.seek(offset)
    data = f.read()
    intact = data.rfind(b"\n") + 1
    index = dict(index)
    _merge(index, _parse(data[:intact], path, kind, first_line=lines + 1), path, kind)
    lines += data[:intact].count(b"\n")
    if truncate and intact < len(data):  # only under the lock is an unfinished line known to be torn
        _parse(data[intact:], path, kind, first_line=lines + 1)  # reports it
        f.truncate(offset + intact)
    _INDEX[key] = (identity, offset + intact, lines, index)
    return index
