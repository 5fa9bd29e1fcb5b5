"""What the hostile-input harness (tests/test_hostile_inputs.py) draws from: bad values for an option, from the
option's own declaration (a `Bounded` range, a path kind, argparse choices), and damaged copies of each kind of
input file (logs, results stores, frames-store metadata, weights)."""

from __future__ import annotations

import argparse
import atexit
import json
import math
import os
import shutil
from collections import Counter
from pathlib import Path

import torch
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from dynplan.cli import Bounded
from dynplan.logs.format import TOPIC_FRAME
from dynplan.paths import PathArgument, PathKind

# --- bad option values ---------------------------------------------------------------------------------------


def _outside(bounds: Bounded) -> st.SearchStrategy[str]:
    """Numbers outside `bounds` (an excluded bound itself included), and strings that are no number of its kind."""
    kind, low, high = bounds.kind, bounds.low, bounds.high
    outside = [st.just(str(v)) for v, excluded in ((low, bounds.open_low), (high, bounds.open_high)) if excluded]
    if low is not None:
        below = st.integers(max_value=math.ceil(low) - 1) if kind is int else st.floats(max_value=low, exclude_max=True)
        outside.append(below.map(str))
    if high is not None:
        above = (
            st.integers(min_value=math.floor(high) + 1) if kind is int else st.floats(min_value=high, exclude_min=True)
        )
        outside.append(above.map(str))
    words = ["", "abc", "nan", "inf", "-inf", "1e999", "0x10", "1,5", " "]
    if kind is int:
        words += ["1.5", "2.0", "1e3"]
    return st.one_of(*outside, st.sampled_from(words))


#: Placeholders a drawn path is made of; `Scene.fill` turns them into real paths in a test's folder.
_HOSTILE = {
    "any": ["", "{devnode}", "{fifo}", "{loop}", "{under_file}/x"],
    "input file": ["{missing}.x", "{folder}", "{dangling}"],
    "input folder": ["{missing}", "{file}", "{dangling}"],
    "output file": ["{folder}", "{input}", "{input_dir}/x.mcap"],
    "output folder": ["{file}", "{input}", "{input_root}"],
}


def hostile_paths(kind: PathKind) -> st.SearchStrategy[str]:
    """Paths that are not of `kind`: empty, a device node, a pipe, a link loop, under a file, missing, the other
    shape, a dangling link; for outputs, the command's inputs or paths inside them; for suffixed files, a file of
    another suffix."""
    values = _HOSTILE["any"] + _HOSTILE[f"{kind.role} {kind.shape}"]
    if kind.suffix:
        values = [*values, "{file}"]  # a regular file without the suffix
    return st.sampled_from(values)


def bad_values(action: argparse.Action, extra: dict[str, list[str]]) -> st.SearchStrategy[str] | None:
    """Bad values for `action`, from its declaration; `extra` lists known-bad values of plain-string options."""
    name = action.option_strings[0] if action.option_strings else action.dest
    if isinstance(action.type, Bounded):
        return _outside(action.type)
    if isinstance(action.type, PathArgument):
        return hostile_paths(action.type.kind)
    if action.choices is not None:
        valid = {str(c) for c in action.choices}
        junk = st.one_of(st.text(min_size=1, max_size=12), st.floats(allow_nan=True).map(str), st.just(""))
        return junk.filter(lambda s: s not in valid and not s.startswith("-"))
    if name in extra:
        return st.sampled_from(extra[name])
    return None


# --- damaged input files ---------------------------------------------------------------------------------------


def rewrite(source, target, edit, topic=TOPIC_FRAME):
    """Copy the MCAP log `source` to `target` with the messages of `topic` replaced by `edit(messages)`, a list of
    mcap `Message` records (file order); everything else is copied as it is."""
    with open(source, "rb") as stream:
        reader = make_reader(stream)
        records = list(reader.iter_messages(log_time_order=False))
        metadata = list(reader.iter_metadata())
    edited = iter(edit([m for _, c, m in records if c.topic == topic]))
    with open(target, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="", library="test")
        schemas, channels = {}, {}
        for schema, channel, _ in records:
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id])  # fmt: skip
        for record in metadata:
            writer.add_metadata(record.name, record.metadata)
        topic_channel = next(channels[c.id] for _, c, _ in records if c.topic == topic)
        for _, channel, message in records:
            if channel.topic == topic:
                message = next(edited, None)
                if message is None:
                    continue
            writer.add_message(channels[message.channel_id] if channel.topic != topic else topic_channel,
                               message.log_time, message.data, message.publish_time, message.sequence)  # fmt: skip
        for message in edited:  # messages the edit added
            writer.add_message(topic_channel, message.log_time, message.data, message.publish_time, message.sequence)
        writer.finish()
    return target


def damage_log(path: Path, how: str, where: float) -> None:
    """Damage the log at `path` in place: "truncate" it, "flip" a byte, or "swap", "repeat" or "drop" one
    `/world/frame` message; `where` in [0, 1) picks the place."""
    data = bytearray(path.read_bytes())
    if how == "truncate":
        path.write_bytes(bytes(data[: int(where * len(data))]))
        return
    if how == "flip":
        data[int(where * len(data))] ^= 0xFF
        path.write_bytes(bytes(data))
        return

    def edit(messages: list) -> list:
        messages = list(messages)
        i = int(where * (len(messages) - 1))
        if how == "swap":
            messages[i], messages[i + 1] = messages[i + 1], messages[i]
        elif how == "repeat":
            messages.insert(i + 1, messages[i])
        else:  # drop
            del messages[i]
        return messages

    rewrite(path, path, edit)


LOG_DAMAGE = st.tuples(st.sampled_from(["truncate", "flip", "swap", "repeat", "drop"]),
                       st.floats(0.0, 1.0, exclude_max=True))  # fmt: skip

_WRONG = ["abc", None, [], {}, -1, 1.5e300, True, ""]


def _retyped(value: object, wrong: int) -> object:
    """A value of another JSON type than `value` (a string for a string would be no damage to its type)."""
    kinds = {bool: "bool", int: "number", float: "number", str: "string", type(None): "null", list: "list", dict: "obj"}
    others = [w for w in _WRONG if kinds[type(w)] != kinds[type(value)]]
    return others[wrong % len(others)]


def damage_json_lines(path: Path, how: str, line: float, key: float, wrong: int) -> str:
    """Damage one JSON line of `path` (the `line`-th, scaled to the file): give a field a value of the wrong type,
    drop a field, cut the line short, or repeat it with another value. Returns what was done, for the report."""
    lines = path.read_text().splitlines()
    n = int(line * len(lines))
    row = json.loads(lines[n])
    field = sorted(row)[int(key * len(row))]
    if how == "retype":
        row[field] = _retyped(row[field], wrong)
        lines[n] = json.dumps(row)
    elif how == "drop":
        del row[field]
        lines[n] = json.dumps(row)
    elif how == "cut":
        lines[n] = lines[n][: max(1, len(lines[n]) // 2)]
    else:  # a second row for the same case with another result
        other = dict(row)
        result = next((k for k in ("outcome", "steps", "goal") if k in other), field)
        other[result] = "death" if other[result] != "death" else "goal"
        lines.append(json.dumps(other))
    path.write_text("\n".join(lines) + "\n")
    return f"{how} {field} at line {n + 1}"


def damage_json(path: Path, how: str, key: float, wrong: int) -> None:
    """Damage a JSON document (a manifest, a zarr.json): retype or drop one (nested) field, or cut it short."""
    text = path.read_text()
    if how == "cut":
        path.write_text(text[: int(key * (len(text.rstrip()) - 1))])  # at least its last character goes
        return
    document = json.loads(text)
    holder, fields = document, sorted(document)
    nested = [k for k in fields if isinstance(document[k], dict) and document[k]]
    if nested and key < 0.5:  # reach into a nested object (a zarr.json's attributes, a codec list's holder)
        holder = document[nested[int(key * 2 * len(nested))]]
        fields = sorted(holder)
    field = fields[int(key * len(fields)) % len(fields)]
    if how == "drop":
        del holder[field]
    else:
        holder[field] = _retyped(holder[field], wrong)
    path.write_text(json.dumps(document))


def damage_weights(path: Path, how: str, where: float, other: Path) -> None:
    """Damage a checkpoint: "truncate" or "flip" its bytes, "reshape" or "nan" one tensor, or replace it with
    `other` (a checkpoint of another configuration or stage)."""
    if how == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: int(where * len(data))])
    elif how == "flip":
        data = bytearray(path.read_bytes())
        data[int(where * len(data))] ^= 0xFF
        path.write_bytes(bytes(data))
    elif how == "other":
        shutil.copyfile(other, path)
    else:
        state = torch.load(path, map_location="cpu", weights_only=False)
        weights = state["model"] if "model" in state else state["state_dict"]
        names = sorted(k for k, v in weights.items() if torch.is_floating_point(v) and v.numel() > 1)
        name = names[int(where * len(names))]
        tensor = weights[name]
        weights[name] = tensor.flatten()[:-1].clone() if how == "reshape" else tensor.clone().fill_(float("nan"))
        torch.save(state, path)


def tree_state(root: Path) -> dict[str, tuple[str, int]]:
    """Every entry under `root`: its kind and (for files) size and a digest, to see that nothing changed. Lock files
    (`*.lock`, beside a store while a writer holds it) are left out."""
    import hashlib

    state = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + [f for f in files if not f.endswith(".lock")]:
            path = Path(folder, name)
            if path.is_symlink() or not (path.is_file() or path.is_dir()):
                state[str(path)] = ("other", 0)
            elif path.is_dir():
                state[str(path)] = ("folder", 0)
            else:
                state[str(path)] = (hashlib.sha256(path.read_bytes()).hexdigest(), path.stat().st_size)
    return state


#: Cases drawn by the harness and their outcomes, by class: (class, outcome) → count.
OUTCOMES: Counter = Counter()


def _report() -> None:
    """`DYNPLAN_HARNESS_REPORT=FILE`: the cases drawn in this process, per class, added to FILE's (docs/robustness.md;
    each test process adds its own)."""
    target = os.environ.get("DYNPLAN_HARNESS_REPORT")
    if not target or not OUTCOMES:
        return
    from dynplan.files import exclusive

    path = Path(target)
    with exclusive(path.with_name(path.name + ".lock")):  # the suite's workers add theirs one at a time
        summary = Counter(json.loads(path.read_text())) if path.is_file() else Counter()
        summary.update({f"{what} {outcome}": n for (what, outcome), n in OUTCOMES.items()})
        path.write_text(json.dumps(dict(sorted(summary.items())), indent=1) + "\n")


atexit.register(_report)
