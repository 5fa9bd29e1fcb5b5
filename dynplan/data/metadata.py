"""The frames store's metadata checked against its format (`dynplan.data.store`), before any chunk is read.

Every `zarr.json` must be a JSON object with what Zarr needs; each array must have the format's data type,
chunk shape, codecs (zstd, then CRC-32C), fill value, chunk key encoding and dimension names, and a shape beyond
the episode axis given by the group's `n_frames`, `height` and `width`; the group's attributes must agree with
one another (its `config` with its `height` and `width`, `pixel_values` and `y_axis` with the format) and its
`episodes` with the arrays' lengths; the consolidated copy of each array's metadata must be the array's own.
What is found is returned as problems; `dynplan.data.verify` reports and repairs them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import BaseModel
from zarr.core.metadata.v3 import ArrayV3Metadata

from dynplan.config import ConfigError
from dynplan.data.store import (
    ARRAYS,
    STORE_FORMAT,
    STORE_VERSION,
    Y_AXIS,
    format_metadata,
    metadata_bytes,
    spec_metadata,
    store_arrays,
    store_world,
)
from dynplan.world import World, world

#: How to start again when the store itself cannot be repaired.
REBUILD = "rebuild the store from its logs: python -m flows.build_datasets LOG_DIR --out NEW.zarr"
#: Why damaged array metadata is not repaired without the logs.
NEEDS_LOGS = f"give the folder of its logs to rewrite its metadata and chunks from the format and them, or {REBUILD}"

#: Why a code array's damaged metadata is not repaired when not repairing.
REENCODE = "a repair removes the array; the next `python -m flows.train vqvae` of its model encodes it again"


@dataclass
class StoreMetadata:
    """What the store's `zarr.json` files say, and what is wrong with them (`problems`: `Damage` fields)."""

    problems: list[dict] = field(default_factory=list)
    episodes: int | None = None  # the committed count; None when it cannot be read
    geometry: tuple[int, int, int] | None = None  # (n_frames, height, width), when the attributes agree
    shapes: dict[str, tuple[int, ...]] = field(default_factory=dict)  # arrays whose metadata reads
    attributes: dict[str, dict] = field(default_factory=dict)  # each such array's attributes
    damaged: set[str] = field(default_factory=set)  # arrays whose metadata is damaged
    consolidated: dict | None = None  # the group's consolidated copies of its arrays' metadata
    arrays: tuple[str, ...] = ARRAYS  # the arrays of episodes its world's store holds

    def problem(self, array: str, kind: str, problem: str, **fields) -> None:
        file = f"{array}/zarr.json" if array else "zarr.json"
        self.problems.append({"array": array, "chunk": file, "kind": kind, "problem": problem, **fields})


def read_json(path: Path) -> tuple[dict | None, str | None]:
    """The JSON object in `path`, or why there is none."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return None, "the file is missing"
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        return None, f"not readable JSON ({error})"
    return (data, None) if isinstance(data, dict) else (None, f"holds JSON {type(data).__name__}, not an object")


def check_metadata(store: str) -> StoreMetadata:
    """Check the group's and each array's `zarr.json` in `store` against the store's format."""
    meta = StoreMetadata()
    data, problem = read_json(Path(store, "zarr.json"))
    if data is not None and (data.get("zarr_format"), data.get("node_type")) != (3, "group"):
        problem = (
            f"not Zarr v3 group metadata (zarr_format {data.get('zarr_format')!r}, node_type {data.get('node_type')!r})"
        )
    if data is not None and not problem and not isinstance(data.get("attributes", {}), dict):
        problem = "its 'attributes' is not a JSON object"
    if problem:
        meta.problem("", "group attributes", problem, unrepaired_because=REBUILD)
        return meta
    attributes = data.get("attributes", {})
    if not attributes and not Path(store, "log_sha256", "zarr.json").is_file():  # a first build has only begun
        meta.episodes = 0
        return meta
    if not attributes:
        meta.problem(
            "",
            "group attributes",
            "the group has no attributes: its episode count, format and geometry are lost",
            unrepaired_because=REBUILD,
        )
        return meta
    episodes = attributes.get("episodes", "missing")  # every build writes it with the format's attributes
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 0:
        meta.problem(
            "",
            "group attributes",
            f"attribute 'episodes' is {episodes!r}, not a count of episodes (an integer ≥ 0)",
            unrepaired_because=REBUILD,
        )
        return meta
    meta.episodes = episodes
    _check_attributes(meta, attributes)
    _read_consolidated(meta, data.get("consolidated_metadata"))
    codes = sorted(p.name for p in Path(store).glob("codes_*") if p.is_dir())
    for name in [*meta.arrays, *codes]:
        if Path(store, name, "zarr.json").is_file():
            _check_array(store, name, meta, attributes.get("format_version"))
    if meta.consolidated is not None:
        missing = sorted(set(meta.shapes) - meta.damaged - set(meta.consolidated))
        extra = sorted(set(meta.consolidated) - set(meta.shapes) - meta.damaged)
        if (missing or extra) and not any(p["kind"] == "consolidated metadata" for p in meta.problems):
            meta.problem(
                "",
                "consolidated metadata",
                f"the consolidated metadata lacks the arrays {missing} and names arrays that are not there {extra}",
                fix={},
            )
    _check_lengths(meta)
    return meta


def _read_consolidated(meta: StoreMetadata, consolidated: object) -> None:
    """The group's consolidated metadata (absent: None), which most readers trust instead of the arrays' own."""
    if consolidated is None:
        return
    copies = consolidated.get("metadata") if isinstance(consolidated, dict) else None
    if not isinstance(copies, dict) or consolidated.get("kind") != "inline":
        meta.problem(
            "",
            "consolidated metadata",
            "the consolidated metadata is not Zarr's inline block of the arrays' metadata",
            fix={},
        )
        copies = {}
    meta.consolidated = copies


def _check_attributes(meta: StoreMetadata, attributes: dict) -> None:
    """The group's attributes: its format, a world config that agrees with its geometry, and the format's
    pixel values and y axis."""
    _check_format(meta, attributes)
    try:
        entry = world(str(store_world(attributes)))
    except ConfigError as error:
        meta.problem("", "group attributes", f"attribute 'world': {error}", unrepaired_because=REBUILD)
        return
    meta.arrays = store_arrays(entry.name)
    try:
        config = entry.config(attributes.get("config"))
    except (ValueError, TypeError, ConfigError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        meta.problem(
            "", "group attributes", f"attribute 'config' is not a world config ({reason})", unrepaired_because=REBUILD
        )
        return
    if config.model_dump() != attributes.get("config"):
        meta.problem(
            "",
            "group attributes",
            f"attribute 'config' {attributes.get('config')} is not a whole world "
            f"config (as a build writes it: {config.model_dump()})",
            unrepaired_because=REBUILD,
        )
        return
    _check_geometry(meta, attributes, entry, config)


def _check_format(meta: StoreMetadata, attributes: dict) -> None:
    """The format's name and version, and the dynplan version that built the store."""
    if attributes.get("format") != STORE_FORMAT:
        meta.problem(
            "",
            "group attributes",
            f"attribute 'format' is {attributes.get('format')!r}, the format's is {STORE_FORMAT!r}",
            unrepaired_because=REBUILD,
        )
    if attributes.get("format_version") not in (STORE_VERSION, "1"):
        meta.problem(
            "",
            "group attributes",
            f"attribute 'format_version' is {attributes.get('format_version')!r}, "
            f"not a version of the format ('1' or {STORE_VERSION!r})",
            unrepaired_because=REBUILD,
        )
    if not isinstance(attributes.get("dynplan_version"), str):  # which dynplan built it: a record, never guessed
        meta.problem(
            "",
            "group attributes",
            f"attribute 'dynplan_version' is {attributes.get('dynplan_version')!r}, not a version string",
            fix={"dynplan_version": "unknown"},
        )


def _check_geometry(meta: StoreMetadata, attributes: dict, entry: World, config: BaseModel) -> None:
    """The frames' geometry against the world config, and the format's pixel values and y axis."""
    geometry = tuple(attributes.get(k) for k in ("n_frames", "height", "width"))
    wanted = (geometry[0], config.height, config.width)
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in geometry) or geometry != wanted:
        meta.problem(
            "",
            "group attributes",
            f"attributes (n_frames, height, width) are {list(geometry)}; the "
            f"config gives height {config.height} and width {config.width}, and n_frames must be an "
            "integer ≥ 1",
            unrepaired_because=REBUILD,
        )
        return
    meta.geometry = geometry
    fix = {"pixel_values": entry.pixel_values(config), "y_axis": Y_AXIS}
    wrong = {k: v for k, v in fix.items() if attributes.get(k) != v}
    if wrong:
        found = ", ".join(f"{k} {attributes.get(k)!r}" for k in wrong)
        meta.problem("", "group attributes", f"attributes {found}; the format's are {wrong}", fix=wrong)


def _check_array(store: str, name: str, meta: StoreMetadata, version: str | None) -> None:
    """One array's `zarr.json`: readable Zarr v3 array metadata, and the format's."""
    data, problem = read_json(Path(store, name, "zarr.json"))
    if data is not None:
        try:
            parsed = ArrayV3Metadata.from_dict(dict(data))
            normal, attributes = json.loads(metadata_bytes(parsed)), dict(parsed.attributes)
        except KeyError as error:
            problem = f"not Zarr v3 array metadata: it lacks the key {error}"
        except Exception as error:  # Zarr's parser meets whatever the file holds and can fail anywhere
            problem = f"not Zarr v3 array metadata: {str(error).splitlines()[0] if str(error) else error!r}"
        else:
            meta.shapes[name], meta.attributes[name] = parsed.shape, attributes
            problem = _format_problem(name, normal, meta.geometry, version) or _normal_form_problem(data, normal)
            copy = _consolidated_problem(name, normal, meta)
            if copy and not problem:  # the array's own is right: consolidating again repairs the copy
                meta.problem("", "consolidated metadata", copy, fix={})
    if problem:
        meta.damaged.add(name)
        reason = REBUILD if not meta.geometry else NEEDS_LOGS if name in meta.arrays else REENCODE
        meta.problem(name, "array metadata", problem, unrepaired_because=reason)


def _normal_form_problem(data: dict, normal: dict) -> str | None:
    """Whether a `zarr.json`'s fields hold what Zarr's parser makes of them: a value of another JSON type (`true`
    for a shape) is read as something else, so it is damage even where the parse succeeds. Fields one side lacks
    are left to the format's own comparison (another Zarr version may write more or fewer)."""
    differing = sorted(k for k in set(data) & set(normal) if type(data[k]) is not type(normal[k]))
    if not differing:
        return None
    found = {k: data.get(k) for k in differing}
    return f"{', '.join(differing)} not as Zarr writes {'it' if len(differing) == 1 else 'them'} ({found})"


def _expected(name: str, actual: dict, geometry: tuple[int, int, int] | None) -> dict | None:
    """The format's metadata for the array `name` of `actual`'s length (None: not known)."""
    shape = actual.get("shape") or [0]
    if name.startswith("codes_"):  # (episode, time, code_y, code_x[, codebook]), one episode per chunk
        length = geometry[0] if geometry else (shape[1] if len(shape) > 1 else 0)
        shape = [shape[0], length, *shape[2:]]
        spec = {
            "shape": shape,
            "chunks": (1, *shape[1:]),
            "dtype": "uint16",
            "dimension_names": actual.get("dimension_names"),
        }
        return json.loads(spec_metadata(spec))
    return json.loads(format_metadata(name, shape[0], geometry)) if geometry else None


def _view(metadata: dict, version: str | None) -> dict:
    """What the format fixes of an array's metadata, by name."""
    grid = metadata.get("chunk_grid", {})
    view = {
        "data type": metadata.get("data_type"),
        "fill value": metadata.get("fill_value"),
        "shape past the episode axis": metadata.get("shape", [])[1:],
        "chunk shape": grid.get("configuration", {}).get("chunk_shape") if grid.get("name") == "regular" else grid,
        "chunk key encoding": metadata.get("chunk_key_encoding"),
        "codecs": metadata.get("codecs"),
        "dimension names": metadata.get("dimension_names"),
        "storage transformers": metadata.get("storage_transformers", []),
    }
    if version == "1":  # version 1 stores had no checksums: `verify_store` reports that on its own
        del view["codecs"]
    return view


def _differences(actual: dict, expected: dict, theirs: str = "the format's") -> str | None:
    """How `actual`'s view differs from `expected`'s (None: it does not)."""
    found = []
    for key, value in expected.items():
        mine = actual.get(key)
        if key == "codecs" and actual.get("data type") != expected.get("data type"):
            mine, value = _without_byte_order(mine), _without_byte_order(value)  # the data type's part of it
        if mine != value:
            shown = [mine, value]
            if key == "codecs" and [c.get("name") for c in mine or []] != [c.get("name") for c in value]:
                shown = [", ".join(str(c.get("name")) for c in codecs or []) for codecs in shown]
            verb = "are" if key in ("codecs", "dimension names", "storage transformers") else "is"
            found.append(f"{key} {verb} {json.dumps(shown[0])} ({theirs}: {json.dumps(shown[1])})")
    return "; ".join(found) or None


def _without_byte_order(codecs: list | None) -> list:
    return [{"name": "bytes"} if c.get("name") == "bytes" else c for c in codecs or []]


def _format_problem(name: str, actual: dict, geometry: tuple[int, int, int] | None, version: str | None) -> str | None:
    expected = _expected(name, actual, geometry)
    if expected is None:
        return None
    return _differences(_view(actual, version), _view(expected, version))


def _consolidated_problem(name: str, actual: dict, meta: StoreMetadata) -> str | None:
    """Whether the group's consolidated copy of the array's metadata, which most readers trust, is its own."""
    if meta.consolidated is None or name not in meta.consolidated:
        return None
    try:
        copy = json.loads(metadata_bytes(ArrayV3Metadata.from_dict(dict(meta.consolidated[name]))))
    except Exception as error:  # as in `_check_array`
        return f"consolidated metadata of array {name!r} is not Zarr v3 array metadata ({error!r})"
    differences = _differences(_view(copy, None), _view(actual, None), theirs="the array's own")
    return f"consolidated metadata of array {name!r}: {differences}" if differences else None


def _check_lengths(meta: StoreMetadata) -> None:
    """The committed count against the arrays' lengths: an attribute that claims more episodes than every array
    holds is damage to the attribute."""
    n = meta.episodes or 0
    lengths = {name: meta.shapes[name][0] for name in meta.arrays if meta.shapes.get(name)}
    if n and len(lengths) == len(meta.arrays) and all(length < n for length in lengths.values()):
        held = ", ".join(f"{name} {length}" for name, length in lengths.items())
        meta.problem(
            "",
            "group attributes",
            f"attribute 'episodes' is {n}, but every array holds fewer ({held})",
            unrepaired_because=REBUILD,
        )


def metadata_problem(store: str | os.PathLike) -> str | None:
    """What a reader of `store` must know before it reads: the first way its metadata differs from the store's
    format, with how to repair it, as one line; None when it is the format's."""
    problems = check_metadata(str(store)).problems
    if not problems:
        return None
    first = problems[0]
    more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
    return (
        f"{store}: {first['chunk']}: {first['problem']}{more}; check and repair it: python -m "
        f"flows.build_datasets --verify {store} LOG_DIR"
    )
