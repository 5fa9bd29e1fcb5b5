"""`python -m lab.probe_inputs`: a probe of bad input, by class (docs/robustness.md), beside the suite's harness.

Each case gives one command (or one API call) good inputs with one thing made bad — a damaged store, a result row
or manifest edited, another world's file, a value of the wrong type, a bad environment variable, an output inside
an input or the package, a limit passed, an interrupt — and is judged as a new user would judge it:

- clear: a non-zero exit (or an exception) with one line naming the bad thing, no traceback, nothing changed;
- unclear: refused, but in several lines, or naming nothing of the case, or as an unexpected error;
- silent: exit 0, or the command went on to its work (its flow is stopped where it would start);
- traceback; lost: a good input or a file of the package changed, or a file of the case's own inputs is gone.

A case whose right answer is to go ahead (an intact store verifies; a numpy integer is an integer) is `ok` when it
does. `--out FILE` writes every case and its outcome as JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path
from unittest import mock

from lab.probe_cases import PACKAGE, ROOT, Case, all_cases

CLASSES = {
    1: "store contents",
    2: "result rows",
    4: "the world at every entrance",
    5: "strict types",
    6: "the environment",
    7: "outputs confined",
    8: "interrupts and limits",
}


class Accepted(BaseException):
    """The command reached its work."""


def _accepted(*args, **kwargs):
    raise Accepted


# --- the scene -----------------------------------------------------------------------------------------------


def build_scene(root: Path) -> None:
    """Good inputs: road logs and a store, a MiniGrid and a Freeway log, weights, small copies of each world's
    results store, the pages made from the road's."""
    from dynplan.data.build import build_frame_store
    from dynplan.data.collect import record_episode
    from dynplan.data.store import inspect_for_store

    for seed in (3, 4):
        record_episode(root / "logs", seed)
    record_episode(root / "mlogs", 1, world_name="minigrid")
    record_episode(root / "flogs", 0, world_name="freeway")
    build_frame_store(root / "store.zarr", [inspect_for_store(p) for p in sorted((root / "logs").glob("*.mcap"))])
    shutil.copytree(ROOT / "dynplan" / "models" / "weights", root / "weights")
    (root / "models" / "default").mkdir(parents=True)
    for stage in ("vqvae", "pixelcnn"):
        shutil.copy(root / "weights" / f"{stage}-default.pt", root / "models" / "default" / f"{stage}.pt")
    _small_store(ROOT / "datasets" / "results", root / "results", "evaluation", 30)
    _small_store(ROOT / "datasets" / "results" / "freeway", root / "fresults", "evaluation", 2)
    _small_store(ROOT / "datasets" / "results" / "minigrid", root / "mresults", "evaluation", 2)
    (root / "pages").mkdir()
    shutil.copy(ROOT / "README.md", root / "pages" / "README.md")
    code, err = run_inprocess("dynplan.evaluation.results", [*_results_argv(root), "--allow-loss"])
    assert code == 0, err


def _small_store(source: Path, target: Path, run: str, rows: int) -> None:
    """A copy of `source`'s run with its first `rows` rows of each technique."""
    (target / "runs" / run).mkdir(parents=True)
    shutil.copy(source / "runs" / run / "manifest.json", target / "runs" / run)
    kept, seen = [], Counter()
    for line in (source / "runs" / run / "episodes.jsonl").read_text().splitlines(keepends=True):
        technique = json.loads(line)["technique"]
        if seen[technique] < rows:
            seen[technique] += 1
            kept.append(line)
    (target / "runs" / run / "episodes.jsonl").write_text("".join(kept))


def _results_argv(root: Path) -> list[str]:
    return ["--results-dir", str(root / "results"), "--docs", str(root / "pages"), "--readme",
            str(root / "pages" / "README.md")]  # fmt: skip


def tree_state(root: Path, skip: Path) -> dict[str, str]:
    state = {}
    for path in sorted(root.rglob("*")):
        ignored = path.name.endswith(".lock") or "__pycache__" in path.parts  # a lock, or bytecode an import wrote
        if path.is_file() and skip not in path.parents and not ignored:
            state[str(path.relative_to(root))] = hashlib.sha256(path.read_bytes()).hexdigest()
    return state


# --- running a case ------------------------------------------------------------------------------------------


def run_inprocess(module: str, argv: list[str], real: bool = False) -> tuple[int | str, str]:
    """Run `python -m module argv` in this process, its flows (unless `real`) and windows stopped where they
    would start."""
    import importlib

    from prefect.flows import Flow

    from dynplan.cli import run_command

    main = importlib.import_module(module).main
    err = io.StringIO()
    with contextlib.ExitStack() as stack:
        stack.enter_context(contextlib.redirect_stderr(err))
        stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
        if not real:
            stack.enter_context(mock.patch.object(Flow, "__call__", _accepted))
        for target in ("flows.worlds.play_window", "flows.serve.serve", "flows.view.install"):
            stack.enter_context(mock.patch(target, _accepted))
        try:
            run_command(main, f"python -m {module}", argv)
            code: int | str = 0
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        except Accepted:
            code = "accepted"
    return code, err.getvalue()


def _interruptible() -> None:
    """In the child: Ctrl-C as a terminal gives it, even where this probe runs in the background (a shell starts
    background jobs with SIGINT ignored, and a child inherits that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_subprocess(case: Case, argv: list[str]) -> tuple[int | str, str]:
    env = {**os.environ, **(case.env or {})}
    for key, value in (case.env or {}).items():
        if value == "":
            env.pop(key, None)
    command = [sys.executable, "-m", case.module, *argv]
    proc = subprocess.Popen(
        command,
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_interruptible,
    )
    if case.interrupt_after is not None:
        time.sleep(case.interrupt_after)
        proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=180)
    except subprocess.TimeoutExpired:
        proc.kill()
        return "hung", "did not finish within 180 s"
    return proc.returncode, err


def run_call(case: Case, folder: Path) -> tuple[int | str, str]:
    try:
        case.call(folder)
    except Exception as error:  # judged like a command's refusal: one line naming the parameter
        return 2, f"{type(error).__name__}: {error}"
    return 0, ""


def judge(case: Case, code: int | str, err: str, changed: bool) -> str:
    lines = err.strip().splitlines()
    if "Traceback" in err:
        return "traceback"
    if changed:
        return "lost"
    if case.expect == "ok":
        return "ok" if code in (0, "accepted") else "unclear"
    if case.interrupt_after is not None:
        return "clear" if code == 130 and lines and "interrupted" in lines[-1] else "unclear"
    if code in (0, "accepted"):
        return "silent"
    if code == "hung":
        return "unclear"
    if case.report:
        named = any(name in line for line in lines for name in case.names)
        return "clear" if named and not any("--debug" in line for line in lines) else "unclear"
    named = lines and any(name in lines[-1] for name in case.names)
    return "clear" if len(lines) == 1 and named and "--debug" not in lines[-1] else "unclear"


def run_case(case: Case, scene: Path, work: Path) -> dict:
    folder = work / "case"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    (folder / "out").mkdir()
    if case.prepare is not None:
        case.prepare(folder)
    fill = {"scene": str(scene), "case": str(folder), "out": str(folder / "out"), "package": str(PACKAGE)}
    argv = [re.sub(r"\{(\w+)\}", lambda m: fill.get(m.group(1), m.group(0)), a) for a in case.argv]
    before = tree_state(scene, folder) | tree_state(PACKAGE, folder)
    own = set(tree_state(folder, folder / "out"))  # the case's own inputs: written to by a repair, never lost
    try:
        if case.call is not None:
            code, err = run_call(case, folder)
        elif case.env is not None or case.interrupt_after is not None:
            code, err = run_subprocess(case, argv)
        else:
            code, err = run_inprocess(case.module, argv, case.real)
    except BaseException:
        code, err = 1, traceback.format_exc()
    changed = before != (tree_state(scene, folder) | tree_state(PACKAGE, folder))
    changed = changed or not own <= set(tree_state(folder, folder / "out"))
    outcome = judge(case, code, err, changed)
    line = (err.strip().splitlines() or [""])[-1][:300]
    return {"class": case.cls, "what": case.what, "outcome": outcome, "exit": code, "line": line}


# --- the cases -----------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m lab.probe_inputs", description=__doc__)
    parser.add_argument("--out", help="write every case and its outcome here (JSON)")
    parser.add_argument("--only", type=int, help="only the cases of this class")
    args = parser.parse_args(argv)
    from prefect.testing.utilities import prefect_test_harness

    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")  # no telemetry from the probe's own API

    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # flows.play's window: SDL's dummy driver is its display

    with tempfile.TemporaryDirectory() as tmp, prefect_test_harness(server_startup_timeout=120):
        work = Path(tmp)
        scene = work / "scene"
        build_scene(scene)
        results = []
        chosen = [c for c in all_cases() if args.only is None or c.cls == args.only]
        for i, case in enumerate(chosen):
            results.append(run_case(case, scene, work))
            print(f"[{i + 1}/{len(chosen)}] {results[-1]['outcome']:9} {case.cls} {case.what}", file=sys.stderr)
    table = Counter((r["class"], r["outcome"]) for r in results)
    print(f"{'class':32} " + " ".join(f"{o:>9}" for o in OUTCOMES))
    for cls, name in CLASSES.items():
        print(f"{cls} {name:30} " + " ".join(f"{table[(cls, o)]:>9}" for o in OUTCOMES))
    print(f"{'all':32} " + " ".join(f"{sum(table[(c, o)] for c in CLASSES):>9}" for o in OUTCOMES))
    for r in results:
        if r["outcome"] not in ("clear", "ok"):
            print(f"  {r['outcome']}: class {r['class']}, {r['what']}: exit {r['exit']}: {r['line']}")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    return {"cases": len(results), "table": {f"{c}:{o}": n for (c, o), n in table.items()}}


OUTCOMES = ("clear", "ok", "unclear", "silent", "traceback", "lost")

if __name__ == "__main__":
    main()
