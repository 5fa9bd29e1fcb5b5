"""The results store: runs with manifests, appends that never duplicate or lose a row (threads, processes, a real
Dask cluster, a killed evaluation), torn rows, stale rows, and Table 1's refusal to mix provenance."""

import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from dynplan.data.collect import record_episode
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.evaluation.store import Run, StoreError, TornRowWarning, evaluation_rows
from dynplan.evaluation.table import aggregate

ROOT = Path(__file__).resolve().parents[1]


def row(seed=EVAL_SEED_START, technique="oracle", k=3, outcome="goal", model=None, **extra):
    base = {"technique": technique, "agent_speed": 1.0, "rollout_steps": k, "seed": seed, "model": model,
            "outcome": outcome, "steps": 1, "playouts": 100, "log_sha256": f"log{seed}", "decision_ms": [1.0],
            "wall_s": 0.1}  # fmt: skip
    if model:
        base["world_model_sha256"] = "w1"
    return {**base, **extra}


def begin(run, role="evaluation", seeds=(EVAL_SEED_START, EVAL_SEED_START + 1), weights="w1", caution=None):
    models = {"default": {"weights_sha256": weights, "weights": [], "caution": caution or {}}}
    return run.begin(role, 100, seeds, {s: f"log{s}" for s in seeds}, models, "cmd")


def test_rows_round_trip_and_a_case_is_written_once(tmp_path):
    run = Run(tmp_path)
    assert run.rows() == [] and run.append(row()) and not run.append(row())  # same case, same provenance
    assert run.append(row(playouts=20))  # same case played differently: a row of its own
    assert run.rows() == [row(), row(playouts=20)]
    assert all(json.loads(line) for line in run.episodes_path.read_text().splitlines())


def test_a_setting_the_code_no_longer_has_keeps_its_rows_apart(tmp_path):
    """A row recorded with a caution setting of other code (`span`, docs/experiments.md) is its own case's row only
    under a manifest that names the setting: it is no duplicate of a row played without it, and never counts for
    a run that did not play with it."""
    with_span, without = Run(tmp_path, "with"), Run(tmp_path, "without")
    learned = dict(technique="samples5", model="default", occupancy=0.1)
    begin(with_span, "validation", caution={"occupancy": 0.1, "span": 1})
    begin(without, "validation", caution={"occupancy": 0.1})
    for run in (with_span, without):
        assert run.append(row(**learned, span=1)) and run.append(row(**learned))  # two provenances, two rows
        assert not run.append(row(**learned, span=1))
    assert with_span.current() == [row(**learned, span=1)]
    assert without.current() == [row(**learned)]
    assert without.find(row(**learned), without.expected(row(**learned))) == row(**learned)


def test_a_torn_last_row_is_reported_cut_and_played_again(tmp_path):
    run = Run(tmp_path)
    run.append(row(EVAL_SEED_START))
    with open(run.episodes_path, "ab") as f:
        f.write(json.dumps(row(EVAL_SEED_START + 1)).encode()[:40])  # a writer killed mid-line
    with pytest.warns(TornRowWarning, match=r"episodes.jsonl: line 2 is torn"):
        assert run.rows() == [row(EVAL_SEED_START)]
    assert Run(tmp_path).find(row(EVAL_SEED_START + 1), {}) is None
    with pytest.warns(TornRowWarning):
        assert run.append(row(EVAL_SEED_START + 1))
    assert run.rows() == [row(EVAL_SEED_START), row(EVAL_SEED_START + 1)]


def test_a_row_another_writer_is_writing_is_left_out_without_a_warning(tmp_path):
    import warnings

    run = Run(tmp_path)
    run.append(row(EVAL_SEED_START))
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys\nfrom dynplan.files import exclusive\n"
        "with exclusive(sys.argv[1]):\n    print('held', flush=True)\n    sys.stdin.readline()"),
        str(run.dir / "episodes.lock")], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with open(run.episodes_path, "ab") as f:
            f.write(json.dumps(row(EVAL_SEED_START + 1)).encode()[:40])  # the holder's row, half written
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert run.rows() == [row(EVAL_SEED_START)]
    finally:
        holder.communicate("done\n", timeout=30)
    with pytest.warns(TornRowWarning, match="line 2 is torn"):  # its writer is gone: torn
        run.rows()


def test_a_damaged_row_names_the_file_and_line(tmp_path):
    run = Run(tmp_path)
    run.append(row(EVAL_SEED_START))
    with open(run.episodes_path, "ab") as f:
        f.write(b"{not json\n")
    with pytest.raises(StoreError, match=r"runs/evaluation/episodes.jsonl:2: not a JSON row"):
        Run(tmp_path).rows()
    (run.manifest_path).write_text("{}")
    with pytest.raises(StoreError, match=r"manifest.json: not a dynplan-run/1 manifest"):
        run.manifest()
    with pytest.raises(StoreError, match=r"run name '\.\./up' is invalid"):
        Run(tmp_path, "../up")


def test_manifest_keeps_its_role_and_stale_rows_stop_counting(tmp_path):
    run = Run(tmp_path)
    begin(run)
    run.append(row(technique="samples5", model="default"))
    run.append(row(EVAL_SEED_START + 1))
    assert len(run.current()) == 2
    with pytest.raises(StoreError, match="has role evaluation; this invocation plays a validation run"):
        begin(run, role="validation")
    manifest = begin(run, weights="w2")  # new weights for the default configuration: its rows are stale
    assert len(manifest["invocations"]) == 2 and manifest["invocations"][1]["code_version"].startswith("dynplan")
    assert run.current() == [row(EVAL_SEED_START + 1)] and len(run.rows()) == 2
    run.append(row(technique="samples5", model="default", world_model_sha256="w2"))
    assert len(run.current()) == 2


def test_table1_refuses_mixed_provenance_naming_the_field(tmp_path):
    a = row(technique="samples5", model="default", margin=1)
    with pytest.raises(ValueError, match=r"samples5 \[default\] at speed 1.0, k=3 mix world_model_sha256 values"):
        aggregate([a, row(EVAL_SEED_START + 1, technique="samples5", model="default", margin=1,
                          world_model_sha256="w2")])  # fmt: skip
    with pytest.raises(ValueError, match="mix margin values"):
        aggregate([a, row(EVAL_SEED_START + 1, technique="samples5", model="default")])
    with pytest.raises(ValueError, match=r"hold seed\(s\) \[1000000\] more than once"):
        aggregate([row(), row(outcome="death")])
    one, two = Run(tmp_path, "evaluation"), Run(tmp_path, "evaluation-2")
    for run in (one, two):
        begin(run)
        run.append(row())
    with pytest.raises(StoreError, match="is in two evaluation runs, 'evaluation' and 'evaluation-2'"):
        evaluation_rows(tmp_path)


def _append_many(root: str, name: str, seeds: list[int]) -> int:
    run = Run(root, name)
    return sum(run.append(row(seed)) for seed in seeds)


def test_concurrent_threads_and_processes_neither_lose_nor_duplicate(tmp_path):
    seeds = list(range(EVAL_SEED_START, EVAL_SEED_START + 40))
    with ThreadPoolExecutor(4) as pool:  # every writer tries every row
        assert sum(pool.map(_append_many, [str(tmp_path)] * 4, ["threads"] * 4, [seeds] * 4)) == 40
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(3) as pool:
        added = pool.starmap(_append_many, [(str(tmp_path), "processes", seeds)] * 3)
    assert sum(added) == 40
    for name in ("threads", "processes"):
        assert sorted(r["seed"] for r in Run(tmp_path, name).rows()) == seeds


@pytest.mark.slow
def test_dask_workers_neither_lose_nor_duplicate_rows(tmp_path, dask_cluster):
    from distributed import Client

    seeds = list(range(EVAL_SEED_START, EVAL_SEED_START + 60))
    run = Run(tmp_path, "dask")
    rows = [row(seed) for seed in seeds + seeds[:30]]  # the first 30 rows twice: one of each pair must lose
    with Client(dask_cluster.address, timeout=60) as client:
        futures = client.map(run.append, rows, pure=False)
        added = client.gather(futures)
        where = {client.who_has(f)[f.key][0] for f in futures if client.who_has(f).get(f.key)}
    assert sum(added) == 60 and len(where) == 2  # both workers appended
    assert sorted(r["seed"] for r in run.rows()) == seeds


@pytest.mark.slow
def test_a_killed_evaluation_resumes_with_every_episode_exactly_once(tmp_path):
    logs, results = tmp_path / "logs", tmp_path / "results"
    for i in range(3):
        record_episode(logs, EVAL_SEED_START + i)
    argv = [sys.executable, "-m", "flows.evaluate", "--techniques", "oracle", "zero", "--agent-speeds", "0.5",
            "--rollout-steps", "10", "--episodes", "3", "--playouts", "400", "--workers", "1", "--log-dir", str(logs),
            "--results-dir", str(results)]  # fmt: skip
    episodes = Run(results).episodes_path
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if episodes.exists() and episodes.read_bytes().count(b"\n") >= 1:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the evaluation finished before it could be killed; give it more work"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the flow and its temporary Prefect server
        proc.wait()
    played = episodes.read_bytes().count(b"\n")
    assert 1 <= played < 6
    with open(episodes, "ab") as f:
        f.write(b'{"technique": "oracle", "agent_')  # as if killed mid-row
    done = subprocess.run([*argv, "--json"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = Run(results).rows()
    assert sorted((r["technique"], r["seed"]) for r in rows) == sorted(
        (t, EVAL_SEED_START + i) for t in ("oracle", "zero") for i in range(3)
    )
    assert episodes.read_bytes().endswith(b"\n") and len(evaluation_rows(results)) == 6


def test_a_run_keeps_its_playouts_and_a_replaced_file_is_read_anew(tmp_path):
    run = Run(tmp_path)
    begin(run)
    with pytest.raises(StoreError, match="plays 100 playouts per decision, not 20: name another run"):
        run.begin("evaluation", 20, [EVAL_SEED_START], {}, {}, "cmd")
    run.append(row(EVAL_SEED_START))
    assert not run.append(row(EVAL_SEED_START))  # the index is warm now
    replaced = tmp_path / "new.jsonl"
    replaced.write_text("\n".join(json.dumps(row(EVAL_SEED_START + i)) for i in range(5)) + "\n")
    replaced.replace(run.episodes_path)  # another file at the same path, longer than the one indexed
    assert not run.append(row(EVAL_SEED_START + 3))  # seen in the new file, not written twice
    assert len(run.rows()) == 5


def test_two_runs_compare_case_by_case(tmp_path):
    from dynplan.evaluation.compare import compare_runs, main

    seeds = (EVAL_SEED_START, EVAL_SEED_START + 1, EVAL_SEED_START + 2)
    a, b = Run(tmp_path / "one", "first"), Run(tmp_path / "two", "second")
    for run in (a, b):
        begin(run, seeds=seeds)
    for seed in seeds:
        a.append(row(seed, decision_ms=[2.0]))
        b.append(row(seed, outcome="death" if seed == seeds[1] else "goal", decision_ms=[1.0]))
    result = compare_runs(a, b)["oracle - speed 1.0 k 3"]
    assert result == {"cases": 3, "outcome_or_steps_differ": 1, "differing_seeds": [seeds[1]], "provenance_differs": 0,
                      "goals": [3, 2], "median_decision_ms": [2.0, 1.0]}  # fmt: skip
    assert main([str(tmp_path / "one"), "first", str(tmp_path / "two"), "second"]) == compare_runs(a, b)
    with pytest.raises(SystemExit):
        main([str(tmp_path / "one"), "first", str(tmp_path / "two"), "nowhere"])


def test_the_lock_file_goes_with_its_writer_and_writers_that_waited_still_exclude_each_other(tmp_path):
    """`exclusive` removes its file on release (no lock file outlives its command), yet four processes that each add
    one to a counter 40 times under it, waiting on files their predecessors removed, lose no addition."""
    from dynplan.files import exclusive, is_held

    lock, counter = tmp_path / "counter.lock", tmp_path / "counter"
    with exclusive(lock):
        assert lock.is_file()
    assert not lock.exists() and not is_held(lock) and not lock.exists()  # asking does not make one either
    counter.write_text("0")
    script = (
        "import sys\nfrom pathlib import Path\nfrom dynplan.files import exclusive\n"
        "lock, counter = sys.argv[1], Path(sys.argv[2])\n"
        "for _ in range(40):\n"
        "    with exclusive(lock):\n"
        "        value = int(counter.read_text())\n"
        "        counter.write_text(str(value + 1))\n"
    )
    writers = [subprocess.Popen([sys.executable, "-c", script, str(lock), str(counter)]) for _ in range(4)]
    assert [w.wait(timeout=120) for w in writers] == [0] * 4
    assert counter.read_text() == "160" and not lock.exists()
