"""The frames store under damage and concurrency: every flipped byte is found, named and repaired from the logs;
plain Zarr readers never see an unfinished append; two conversions into one store both finish correctly."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import dask.array as da
import numpy as np
import pytest
import xarray as xr
import zarr

from dynplan.data.build import build_frame_store_from_logs
from dynplan.data.chunks import COMPRESSORS, ChunkError
from dynplan.data.datasets import FrameDataset
from dynplan.data.store import ARRAYS, fingerprint, list_logs, lock_path
from dynplan.data.verify import verify_store

ROOT = Path(__file__).resolve().parents[1]


def contents(store) -> dict[str, np.ndarray]:
    group = zarr.open_group(str(store), mode="r", use_consolidated=False)
    return {name: group[name][:] for name in ARRAYS}


def chunk_files(store) -> list[Path]:
    return sorted(p for name in ARRAYS for p in (Path(store) / name / "c").rglob("*") if p.is_file())


def flip(path: Path, rng: np.random.Generator) -> int:
    data = bytearray(path.read_bytes())
    at = int(rng.integers(len(data)))
    data[at] ^= 1 << int(rng.integers(8))
    path.write_bytes(bytes(data))
    return at


@pytest.fixture
def store(tmp_path, recorded_logs):
    out = tmp_path / "frames.zarr"
    build_frame_store_from_logs(out, list_logs(recorded_logs))
    return out


def test_every_flipped_byte_is_reported_with_its_episode_and_repaired(store, recorded_logs):
    original, before = contents(store), fingerprint(store)
    rng = np.random.default_rng(0)
    files = chunk_files(store)
    assert len(files) == 10  # six frames chunks, one each of goal, seed, log_name, log_sha256
    for path in files:
        for _ in range(3):  # three flips per chunk, anywhere in it (header, payload or checksum)
            flip(path, rng)
            report = verify_store(store)
            (damage,) = report.damage
            array, *key = path.relative_to(store).parts
            assert (damage.array, damage.chunk) == (array, "/".join(key))
            assert "episode" in damage.episodes and not damage.repaired
            repaired = verify_store(store, recorded_logs)
            assert [d.repaired for d in repaired.damage] == [True], repaired.to_dict()
            assert verify_store(store).damage == []
    after = contents(store)
    for name in ARRAYS:
        np.testing.assert_array_equal(after[name], original[name])
    assert fingerprint(store) == before


def test_readers_name_the_damaged_chunk_and_episode(store):
    flip(store / "frames" / "c" / "3" / "0" / "0" / "0", np.random.default_rng(1))
    dataset = FrameDataset(store, "all")
    with pytest.raises(ChunkError, match=r"array 'frames', chunk c/3/0/0/0 \(episode 3, seed 3\) is damaged: its "
                                         r"CRC-32C does not match"):  # fmt: skip
        dataset[3 * 407]
    assert dataset[0].shape == (48, 48)  # the intact episodes still read
    with pytest.raises(ValueError, match="checksum"):  # a reader without dynplan gets an error, not wrong pixels
        zarr.open_group(str(store), mode="r")["frames"][3]
    flip(store / "seed" / "c" / "0", np.random.default_rng(2))
    with pytest.raises(ChunkError, match=r"array 'seed', chunk c/0 \(episodes 0–5\)"):
        FrameDataset(store, "all")


def test_a_missing_chunk_is_damage_not_zeros(store, recorded_logs):
    (store / "frames" / "c" / "2" / "0" / "0" / "0").unlink()
    (damage,) = verify_store(store).damage
    assert damage.chunk == "c/2/0/0/0" and damage.problem == "the chunk file is missing"
    assert "seed 2" in damage.episodes and "episode_0000000002.mcap" in damage.episodes
    assert verify_store(store, recorded_logs).damage[0].repaired


def test_lost_identity_is_recovered_from_the_other_records(store, recorded_logs):
    original = contents(store)
    for name in ("seed", "log_sha256"):  # only the log names are left to find each episode's log by
        flip(store / name / "c" / "0", np.random.default_rng(3))
    report = verify_store(store, recorded_logs)
    assert sorted(d.array for d in report.damage if d.repaired) == ["log_sha256", "seed"]
    for name in ARRAYS:
        np.testing.assert_array_equal(contents(store)[name], original[name])
    flip(store / "log_name" / "c" / "0", np.random.default_rng(4))
    flip(store / "log_sha256" / "c" / "0", np.random.default_rng(5))
    flip(store / "seed" / "c" / "0", np.random.default_rng(6))
    report = verify_store(store, recorded_logs)
    assert len(report.unrepaired) == 3
    assert all("lost its seed, log name and checksum" in d.unrepaired_because for d in report.unrepaired)


def test_a_rebuild_checks_what_it_skips_and_repairs_it(store, recorded_logs):
    original = contents(store)
    flip(store / "frames" / "c" / "4" / "0" / "0" / "0", np.random.default_rng(7))
    report = build_frame_store_from_logs(store, list_logs(recorded_logs))
    assert report.added == [] and len(report.skipped) == 6 and not report.failed
    assert len(report.repaired) == 1 and "chunk c/4/0/0/0 (episode 4, seed 4" in report.repaired[0]
    np.testing.assert_array_equal(contents(store)["frames"], original["frames"])


def test_a_rebuild_without_the_damaged_episodes_log_fails_naming_it(store, recorded_logs, tmp_path):
    logs = tmp_path / "some"
    logs.mkdir()
    for path in list_logs(recorded_logs)[:3]:
        shutil.copy(path, logs)
    flip(store / "frames" / "c" / "5" / "0" / "0" / "0", np.random.default_rng(8))
    report = build_frame_store_from_logs(store, list_logs(logs))
    (reason,) = report.failed.values()
    assert "chunk c/5/0/0/0 (episode 5, seed 5" in reason and "not repaired: no log with SHA-256" in reason


def test_verify_command_reports_then_repairs(store, recorded_logs):
    flip(store / "goal" / "c" / "0" / "0" / "0", np.random.default_rng(9))
    command = [sys.executable, "-m", "flows.build_datasets", "--verify", str(store)]
    found = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert found.returncode == 1 and "Traceback" not in found.stderr
    assert "array 'goal', chunk c/0/0/0 (episode 0, seed 0, log episode_0000000000.mcap;" in found.stderr
    assert "give the folder of its logs to repair what they determine" in found.stderr
    fixed = subprocess.run([*command, str(recorded_logs)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert fixed.returncode == 0, fixed.stderr
    assert "1 damaged, 1 repaired" in fixed.stdout
    again = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and "0 damaged" in again.stdout


def test_plain_readers_never_see_an_unfinished_append(tmp_path, recorded_logs, monkeypatch):
    import dynplan.data.build as store_module

    store = tmp_path / "frames.zarr"
    logs = list_logs(recorded_logs)
    build_frame_store_from_logs(store, logs[:2])
    original = store_module.write_rows

    def crash(array, start, values):
        if array.basename == "log_sha256":  # frames, goal, seed and names of the new rows are written by now
            raise KeyboardInterrupt("killed mid-append")
        original(array, start, values)

    monkeypatch.setattr(store_module, "write_rows", crash)
    with pytest.raises(KeyboardInterrupt):
        build_frame_store_from_logs(store, logs)
    assert da.from_zarr(str(store), component="frames").shape[0] == 2
    assert all(zarr.open_array(str(store / name), mode="r").shape[0] == 2 for name in ARRAYS)
    assert xr.open_zarr(store, consolidated=False).sizes["episode"] == 2
    assert xr.open_zarr(store).sizes["episode"] == 2
    monkeypatch.setattr(store_module, "write_rows", original)
    report = build_frame_store_from_logs(store, logs)
    assert report.episodes == 6 and len(report.added) == 4
    assert list(zarr.open_group(str(store), mode="r")["seed"][:]) == list(range(6))
    assert verify_store(store).damage == []


BUILD = "from dynplan.data.build import build_frame_store_from_logs as b\n" \
        "from dynplan.data.store import list_logs as l\nimport sys\n" \
        "r = b(sys.argv[1], l(sys.argv[2])); print(\"added\", len(r.added), r.episodes)"  # fmt: skip


@pytest.mark.slow
def test_two_conversions_into_one_store_both_finish(tmp_path, recorded_logs):
    firsts, lasts = tmp_path / "a", tmp_path / "b"
    for folder, picks in ((firsts, slice(0, 4)), (lasts, slice(2, 6))):  # overlapping: episodes 2 and 3 in both
        folder.mkdir()
        for path in list_logs(recorded_logs)[picks]:
            shutil.copy(path, folder)
    store = tmp_path / "frames.zarr"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys\nfrom dynplan.files import exclusive\n"
        "with exclusive(sys.argv[1]):\n    print('held', flush=True)\n    sys.stdin.readline()"),
        str(lock_path(store))],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert holder.stdout.readline().strip() == "held"
    procs = [subprocess.Popen([sys.executable, "-c", BUILD, str(store), str(logs)], cwd=ROOT, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE) for logs in (firsts, lasts)]  # fmt: skip
    for proc in procs:  # both say that they wait for the lock's holder, and wait
        waiting = "another build or repair holds the store (held by pid"
        assert any(waiting in line for line in iter(proc.stderr.readline, ""))
        assert proc.poll() is None
    holder.communicate("release\n", timeout=30)
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    added = sorted(int(out.split("added ")[-1].split()[0]) for out, _ in outs)
    assert added == [2, 4]  # the second adds only what the first did not
    group = zarr.open_group(str(store), mode="r")
    assert sorted(group["seed"][:]) == list(range(6)) and group.attrs["episodes"] == 6
    assert verify_store(store).damage == []


def test_a_store_of_another_format_version_is_refused_with_what_to_do(store, recorded_logs):
    group = zarr.open_group(str(store), mode="r+", use_consolidated=False)
    group.attrs["format_version"] = "1"
    with pytest.raises(ValueError, match="format version '1'; this dynplan extends version '?2'? .*build a new one"):
        build_frame_store_from_logs(store, list_logs(recorded_logs))


def store_bytes(store) -> dict[str, bytes]:
    return {str(p.relative_to(store)): p.read_bytes() for p in sorted(Path(store).rglob("*")) if p.is_file()}


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def test_a_damaged_data_type_is_never_written_through_and_is_repaired_from_the_logs(store, recorded_logs):
    before, print_before = store_bytes(store), fingerprint(store)
    edit_json(store / "frames" / "zarr.json", lambda meta: meta.update(data_type="int16"))
    damaged = store_bytes(store)
    (damage,) = verify_store(store).damage  # no logs: reported, and nothing is written
    assert (damage.array, damage.kind, damage.chunk, damage.repaired) == ("frames", "array metadata",
                                                                           "frames/zarr.json", False)  # fmt: skip
    assert damage.problem == 'data type is "int16" (the format\'s: "uint8")'
    assert "give the folder of its logs" in damage.describe()
    assert "python -m flows.build_datasets LOG_DIR --out NEW.zarr" in damage.describe()
    assert store_bytes(store) == damaged
    (damage,) = verify_store(store, recorded_logs).damage
    assert damage.repaired and "rewritten as the format's and its chunks from the logs" in damage.describe()
    assert store_bytes(store) == before and fingerprint(store) == print_before
    assert verify_store(store).damage == []


def test_a_changed_chunk_shape_and_missing_codecs_are_found_and_repaired(store, recorded_logs):
    before = store_bytes(store)
    edit_json(store / "frames" / "zarr.json",
              lambda meta: meta["chunk_grid"]["configuration"].update(chunk_shape=[2, 407, 48, 48]))  # fmt: skip
    edit_json(store / "seed" / "zarr.json", lambda meta: meta.update(codecs=meta["codecs"][:2]))
    problems = {d.array: d.problem for d in verify_store(store, repair=False).damage}
    assert problems == {"frames": "chunk shape is [2, 407, 48, 48] (the format's: [1, 407, 48, 48])",
                        "seed": 'codecs are "bytes, zstd" (the format\'s: "bytes, zstd, crc32c")'}  # fmt: skip
    assert all(d.repaired for d in verify_store(store, recorded_logs).damage)
    assert store_bytes(store) == before


def test_unreadable_metadata_is_named_without_a_traceback(store, recorded_logs):
    (store / "goal" / "zarr.json").write_text('{"shape": [6')
    edit_json(store / "log_name" / "zarr.json", lambda meta: meta.pop("data_type"))
    problems = {d.array: d.problem for d in verify_store(store, repair=False).damage}
    assert problems["goal"].startswith("not readable JSON (Expecting")
    assert problems["log_name"] == "not Zarr v3 array metadata: it lacks the key 'data_type'"
    command = [sys.executable, "-m", "flows.build_datasets", "--verify", str(store)]
    found = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert found.returncode == 1 and "Traceback" not in found.stderr
    assert f"{store}: array 'goal', array metadata goal/zarr.json (every episode): not readable JSON" in found.stderr
    fixed = subprocess.run([*command, str(recorded_logs)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert fixed.returncode == 0, fixed.stderr
    assert verify_store(store).damage == []


def test_an_episode_count_that_the_arrays_do_not_hold_is_reported_with_how_to_rebuild(store, recorded_logs):
    group = zarr.open_group(str(store), mode="r+", use_consolidated=False)
    group.attrs["episodes"] = 9
    (damage,) = verify_store(store, recorded_logs).damage
    assert (damage.array, damage.kind, damage.repaired) == ("", "group attributes", False)
    assert damage.problem == ("attribute 'episodes' is 9, but every array holds fewer (frames 6, goal 6, seed 6, "
                              "log_name 6, log_sha256 6)")  # fmt: skip
    assert damage.unrepaired_because.endswith("python -m flows.build_datasets LOG_DIR --out NEW.zarr")
    group.attrs["episodes"] = "6"
    (damage,) = verify_store(store, recorded_logs).damage
    assert damage.problem == "attribute 'episodes' is '6', not a count of episodes (an integer ≥ 0)"
    report = build_frame_store_from_logs(store, list_logs(recorded_logs))  # a build refuses to go on
    assert report.added == [] and list(report.failed) == [f"{store}/zarr.json"]


def test_format_attributes_and_consolidated_copies_are_repaired_without_logs(store):
    def damage(meta):
        meta["attributes"]["pixel_values"] = {"free": 0}
        meta["consolidated_metadata"]["metadata"]["frames"]["data_type"] = "int16"

    edit_json(store / "zarr.json", damage)
    assert zarr.open_group(str(store), mode="r")["frames"].dtype == np.int16  # what a plain reader would trust
    report = verify_store(store)
    assert sorted(d.kind for d in report.damage) == ["consolidated metadata", "group attributes"]
    assert all(d.repaired for d in report.damage), report.to_dict()
    assert zarr.open_group(str(store), mode="r")["frames"].dtype == np.uint8
    assert zarr.open_group(str(store), mode="r").attrs["pixel_values"]["sedan"] == 144
    assert verify_store(store).damage == []


def test_a_code_array_with_damaged_metadata_is_removed_to_be_encoded_again(store):
    group = zarr.open_group(str(store), mode="r+", use_consolidated=False)
    dims = ("episode", "time", "code_y", "code_x")
    codes = group.create_array("codes_test", shape=(6, 407, 6, 6), chunks=(1, 407, 6, 6), dtype="uint16",
                               dimension_names=dims, compressors=COMPRESSORS)  # fmt: skip
    codes[:] = np.arange(6 * 407 * 36, dtype=np.uint16).reshape(6, 407, 6, 6)
    codes.attrs["episodes"] = 6
    (late,) = verify_store(store).damage  # the consolidated copy lags until it is consolidated again
    assert late.kind == "consolidated metadata" and "lacks the arrays ['codes_test']" in late.problem and late.repaired
    assert verify_store(store).damage == []
    edit_json(store / "codes_test" / "zarr.json", lambda meta: meta.update(fill_value=7))
    (damage,) = verify_store(store).damage
    assert damage.problem == "fill value is 7 (the format's: 0)"
    assert damage.repaired and "the next `python -m flows.train vqvae` of its model encodes it again" in damage.action
    assert not (store / "codes_test").exists() and verify_store(store).damage == []


def _write_through_zarr(store: Path, name: str, row: int, change) -> None:
    """Change row `row` of array `name` as any Zarr writer would: a valid chunk, a valid checksum."""
    array = zarr.open_group(str(store), mode="r+", use_consolidated=False)[name]
    values = array[row]
    array[row] = change(values)


def test_what_a_chunk_holds_is_checked_not_only_its_checksum(store, recorded_logs):
    """A pixel outside the world's values, a seed outside its range, a goal off the frame: each written with a
    valid checksum, each reported with its episode and repaired from the logs."""

    def pixel(frames):
        frames[5, 3, 4] = 255
        return frames

    _write_through_zarr(store, "frames", 1, pixel)
    zarr.open_group(str(store), mode="r+", use_consolidated=False)["seed"][2] = -7
    _write_through_zarr(store, "goal", 3, lambda goal: np.where(np.arange(len(goal))[:, None] == 9, np.nan, goal))
    problems = {d.array: d.problem for d in verify_store(store).damage}
    assert problems["frames"].startswith("episode 1 holds pixel value 255 at frame 5, row 3, column 4, not one of")
    assert problems["seed"] == "episode 2 has seed -7, outside the world's [0, 4611686018427387904]"
    assert problems["goal"].startswith("episode 3's goal at frame 9 is (nan, nan), not on the 48 × 48 frame")
    assert all(d.repaired for d in verify_store(store, recorded_logs).damage)
    assert verify_store(store).damage == []


def test_another_episodes_intact_chunk_is_found_by_its_first_frame(store, recorded_logs):
    """A chunk copied over another carries a valid checksum and the world's palette; its first frame is not what
    its episode's seed records: `--verify` names it and repairs it from the logs, training refuses it."""
    shutil.copy(store / "frames" / "c" / "1" / "0" / "0" / "0", store / "frames" / "c" / "3" / "0" / "0" / "0")
    (damage,) = verify_store(store).damage
    assert (damage.array, damage.chunk) == ("frames", "c/3/0/0/0")
    assert damage.problem == "episode 3's first frame is not what its seed 3 records (another episode's?)"
    with pytest.raises(ChunkError, match=r"chunk c/3/0/0/0 \(episode 3, seed 3\) .*first frame is not what its seed"):
        FrameDataset(store, "all")[3 * 407]
    assert all(d.repaired for d in verify_store(store, recorded_logs).damage) and verify_store(store).damage == []


def test_training_reads_refuse_what_is_not_an_episode(store):
    """A model never trains on a missing chunk's fill values or on a pixel outside the world's."""
    (store / "frames" / "c" / "2" / "0" / "0" / "0").unlink()
    with pytest.raises(ChunkError, match=r"chunk c/2/0/0/0 \(episode 2\) is damaged: the chunk file is missing"):
        FrameDataset(store, "all")  # at once, before any batch


def test_a_pixel_outside_the_worlds_values_is_refused_when_read(store):
    def pixel(frames):
        frames[0, 0, 0] = 7
        return frames

    _write_through_zarr(store, "frames", 4, pixel)
    dataset = FrameDataset(store, "all")
    with pytest.raises(ChunkError, match="episode 4 holds pixel value 7 at frame 0, row 0, column 0"):
        dataset[4 * 407]


def test_a_chunk_of_fill_values_is_written_so_a_fresh_store_verifies_intact(tmp_path, recorded_logs):
    """Seed 0 alone: the `seed` chunk holds only the fill value, which Zarr would not write; dynplan writes every
    chunk, so `--verify` finds the store intact and a missing chunk is always damage."""
    store = tmp_path / "seed0.zarr"
    build_frame_store_from_logs(store, list_logs(recorded_logs)[:1])
    assert (store / "seed" / "c" / "0").is_file()
    assert verify_store(store).damage == []
