"""Import a folder of per-episode result files into a run of the results store.

Before the results store, every evaluated episode was its own JSON file, `FOLDER/episodes/<technique>[-<model>]/
speed<s>_k<k>/seed<N>.json`, holding the same fields as a store row. `python -m dynplan.evaluation.legacy FOLDER
--run NAME --role ROLE` appends them to the run `NAME` and writes its manifest from the rows' own provenance;
a folder whose rows of one world model were played with different weights, caution or playouts is refused.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Mapping
from pathlib import Path

from dynplan.evaluation.store import CASE_KEYS, FORMAT, ROLES, Run, StoreError, case_key
from dynplan.models.caution import Caution

#: Fields every per-episode result holds besides its case (`model` may be null: the oracle's).
REQUIRED = ("playouts", "log_sha256")
#: What an imported run's manifest says of its code version: the files never recorded one.
UNRECORDED = "unrecorded (imported from per-episode result files)"


def read_folder(folder: str | os.PathLike) -> list[dict]:
    """The per-episode results under `folder`/episodes, in path order (a damaged file is named)."""
    rows = []
    for path in sorted(Path(folder).glob("episodes/*/*/seed*.json")):
        try:
            row = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise StoreError(f"{path}: not a JSON result ({error})") from None
        missing = [k for k in (*CASE_KEYS, *REQUIRED) if not isinstance(row, dict) or k not in row]
        if missing:
            raise StoreError(f"{path}: not a per-episode result: it lacks {', '.join(missing)}")
        rows.append(row)
    return rows


def _one(values: set, what: str, folder) -> object:
    if len(values) != 1:
        raise StoreError(f"{folder}: its results mix {what} {sorted(map(str, values))}; import them as separate runs")
    return next(iter(values))


def import_folder(folder: str | os.PathLike, run: Run, role: str, commands: list[str],
                  weights: Mapping[str, list[str]] | None = None) -> int:  # fmt: skip
    """Append the results of `folder` to `run` with a manifest built from them; returns the rows imported.
    `commands`: the command lines that played them (for the manifest); `weights`: model → the weights' paths."""
    rows = read_folder(folder)
    if not rows:
        raise StoreError(f"{folder}: no per-episode results under episodes/")
    if len({case_key(r) for r in rows}) != len(rows):
        raise StoreError(f"{folder}: holds an episode twice")
    playouts = _one({r["playouts"] for r in rows}, "playouts", folder)
    world_models = {}
    for model in sorted({r["model"] for r in rows if r.get("model")}):
        mine = [r for r in rows if r.get("model") == model]
        sha = _one({r.get("world_model_sha256") for r in mine}, f"{model} weights", folder)
        if sha is None:
            raise StoreError(f"{folder}: the rows of world model {model!r} do not record its weights' SHA-256")
        caution = _one({json.dumps({k: r[k] for k in Caution.model_fields if k in r}) for r in mine},
                       f"{model} caution", folder)  # fmt: skip
        world_models[model] = {"weights_sha256": sha, "weights": list((weights or {}).get(model, [])),
                               "caution": json.loads(caution)}  # fmt: skip
    logs: dict[int, str] = {}
    for r in rows:
        if logs.setdefault(r["seed"], r["log_sha256"]) != r["log_sha256"]:
            raise StoreError(f"{folder}: seed {r['seed']} was played against two different logs")
    manifest = {"format": FORMAT, "name": run.name, "role": role, "playouts": playouts,
                "episode_seeds": sorted(logs), "log_sha256": {str(s): h for s, h in sorted(logs.items())},
                "world_models": world_models,
                "invocations": [{"command": c, "code_version": UNRECORDED, "started": None}
                                for c in commands]}  # fmt: skip
    if run.exists() or run.episodes_path.exists():
        raise StoreError(f"{run.dir}: run {run.name!r} exists already; import into a new run")
    run.write_manifest(manifest)
    return sum(run.append(r) for r in rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dynplan.evaluation.legacy", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("folder", help="a folder holding episodes/<group>/<k>/seed<N>.json")
    parser.add_argument("--run", required=True, help="the new run's name")
    parser.add_argument("--role", required=True, choices=ROLES)
    parser.add_argument("--results-dir", default="datasets/results", help="the results store (default: %(default)s)")
    parser.add_argument("--command", action="append", default=[], help="a command line that played them (repeatable)")
    parser.add_argument("--weights", action="append", default=[], metavar="MODEL=PATH[,PATH]",
                        help="the weights a world model's rows were played with (repeatable)")  # fmt: skip
    args = parser.parse_args(argv)
    weights = {}
    for item in args.weights:
        model, sep, paths = item.partition("=")
        if not sep or not paths:
            parser.error(f"--weights {item!r}: expected MODEL=PATH[,PATH]")
        weights[model] = paths.split(",")
    try:
        count = import_folder(args.folder, Run(args.results_dir, args.run), args.role, args.command, weights)
    except StoreError as error:
        parser.exit(2, f"python -m dynplan.evaluation.legacy: error: {error}\n")
    print(f"{count} results imported into {Run(args.results_dir, args.run).dir}")
    return count


if __name__ == "__main__":
    main()
