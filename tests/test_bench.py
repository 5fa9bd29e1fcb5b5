"""The benchmarks' command line and a few benchmarks run small."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_bench_world_prints_case_figure_values():
    proc = subprocess.run(
        [sys.executable, "-m", "dynplan.bench", "world", "--json"], cwd=ROOT, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(proc.stdout)["world"]
    assert figures["frames_per_s"] > 0 and figures["stepwise_frames_per_s"] > 0


def test_bench_unknown_name_is_a_clear_error():
    proc = subprocess.run([sys.executable, "-m", "dynplan.bench", "wrold"], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 2
    assert "invalid choice: 'wrold'" in proc.stderr


def test_bench_device_applies_to_the_world_model_benchmarks_only(capsys):
    from dynplan.bench.__main__ import main

    with pytest.raises(SystemExit):
        main(["world", "--device", "cpu"])
    assert "the world benchmark runs on the CPU only; --device applies to evaluation" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluation", "--device", "tpu"])
    assert "--device: device must be" in capsys.readouterr().err


def test_bench_decision_times_the_committed_paper_world_model():
    from dynplan.bench.decision import bench_decision

    results = bench_decision(decisions=3, threads=1)
    paper = results["model_samples5_k3_paper"]
    assert paper["weights"] == "committed" and paper["median_ms"] > 0
    assert results["model_samples5_k3"]["weights"] in {"committed", "untrained"}


def test_bench_prior_reports_windows_per_second_against_its_baseline():
    from dynplan.bench.prior import bench_prior

    results = bench_prior(steps=1, repeats=1, threads=1, presets=("paper",))
    paper = results["paper"]
    assert paper["train_windows_per_s"] > 0 and paper["baseline_windows_per_s"] > 0 and paper["rows_windows_per_s"] > 0
    assert paper["speedup_vs_rows"] == round(paper["train_windows_per_s"] / paper["rows_windows_per_s"], 2)


def test_bench_table_prints_numbers_and_labels(monkeypatch, capsys):
    from dynplan import bench
    from dynplan.bench.__main__ import main

    monkeypatch.setitem(bench.BENCHMARKS, "fake", lambda: {"case": {"median_ms": 1234.5, "weights": "committed"}})
    assert main(["fake"]) == 0
    printed = capsys.readouterr().out
    assert "1,234.5" in printed and "committed" in printed  # a label among the figures (it once crashed the table)


def test_table1_grids_count_each_world_and_frame_once_when_shared():
    from dynplan.bench.sharing import table1_grids

    def row(technique, k, steps, seed=1, speed=1.0):
        return {"technique": technique, "model": "default", "agent_speed": speed, "rollout_steps": k, "seed": seed,
                "steps": steps}  # fmt: skip

    # frames 4, 5, 6: mid k=3 asks 3 + 3 + 3 greedy grids, futures5 k=1 asks 1 + 5 at frames 4 and 5; shared: the
    # greedy chain 3 long at every frame, the futures 1 long at two
    counted = table1_grids([row("mid", 3, 3), row("futures5", 1, 2), {"technique": "oracle", "model": None}])
    assert counted == {"grids_default": {"per_case": 9 + 12, "shared": 9 + 10, "ratio": round(21 / 19, 2)}}
    # another world shares nothing; the last frames' horizons stop at the timeout frame (T - 1 = 202 at 2x)
    late = table1_grids([row("mid", 10, 199), row("mid", 10, 199, seed=2)])["grids_default"]
    assert late["per_case"] == late["shared"] == 2 * (10 * 189 + sum(range(10)))


def test_bench_batched_times_greedy_and_sampled_grids_both_ways():
    from dynplan.bench.generation import bench_batched

    results = bench_batched(batches=(2,), repeats=1, threads=1)
    assert set(results) == {f"{m}_{kind}_batch2" for m in ("paper", "default") for kind in ("greedy", "sampled")}
    for name, figures in results.items():
        assert figures["kernel_ms_per_grid"] > 0 and figures["batched_ms_per_grid"] > 0
        assert figures["occupancy_table"] == name.startswith("default_greedy")


def test_bench_decoding_times_each_configurations_decoding_draw_and_samples_against_their_plain_formulations():
    from dynplan.bench.decoding import bench_decoding

    results = bench_decoding(repeats=1)
    assert set(results) == {"paper", "default"}
    for figures in results.values():
        assert figures["decode_ms_per_frame"] > 0 and figures["decode_plain_ms_per_frame"] > 0
        assert figures["draw_compiled_ms_per_position"] > 0 and figures["threads"] == 1
    assert results["default"]["codes"] == 4096 and results["paper"]["codes"] == 512
    # only the paper's DMoL decoder times its samples in blocks against the whole batch's
    assert results["paper"]["5_samples_blocked_ms_per_frame"] > 0 and "samples_ratio" not in results["default"]
