"""LeRobot datasets written with pyarrow, laid out as LeRobot writes them (v3.0 and v2.1; no videos, no
tasks table): what the tests and the benchmark validate (tests/test_lerobot.py, tools/bench/lerobot.py).
The values are given in the dataset's units; the layout is the only thing written here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .lerobot import pyarrow_parquet

SO101_NAMES = ["shoulder_pan.pos", "shoulder_lift.pos", "elbow_flex.pos", "wrist_flex.pos", "wrist_roll.pos",
               "gripper.pos"]


def info(fps: float, names=SO101_NAMES, version: str = "v3.0", **extra) -> dict:
    vector = {"dtype": "float32", "shape": [len(names)], "names": list(names), **extra}
    scalar = lambda dtype: {"dtype": dtype, "shape": [1], "names": None}
    layout = ({"data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"} if version.startswith("v3")
              else {"data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"})
    return {"codebase_version": version, "robot_type": "so101_follower", "fps": fps, **layout,
            "features": {"action": vector, "observation.state": dict(vector), "timestamp": scalar("float32"),
                         "frame_index": scalar("int64"), "episode_index": scalar("int64"), "index": scalar("int64"),
                         "task_index": scalar("int64")}}


def frames_table(episodes: list, fps: float, fixed: bool = True, start: int = 0):
    """One table of every episode's frames: `episodes` a list of (episode_index, values (N, k))."""
    import pyarrow as pa
    columns = {k: [] for k in ("action", "observation.state", "timestamp", "frame_index", "episode_index", "index")}
    index = start
    for e, values in episodes:
        n = len(values)
        columns["action"] += [list(map(float, row)) for row in values]
        columns["observation.state"] += [list(map(float, row)) for row in values]
        columns["timestamp"] += list(np.arange(n) / fps)
        columns["frame_index"] += list(range(n))
        columns["episode_index"] += [e] * n
        columns["index"] += list(range(index, index + n))
        index += n
    width = len(episodes[0][1][0]) if episodes and len(episodes[0][1]) else 6
    vector = pa.list_(pa.float32(), width) if fixed else pa.list_(pa.float32())
    return pa.table({"action": pa.array(columns["action"], type=vector),
                     "observation.state": pa.array(columns["observation.state"], type=vector),
                     "timestamp": pa.array(columns["timestamp"], type=pa.float32()),
                     "frame_index": pa.array(columns["frame_index"], type=pa.int64()),
                     "episode_index": pa.array(columns["episode_index"], type=pa.int64()),
                     "index": pa.array(columns["index"], type=pa.int64()),
                     "task_index": pa.array([0] * len(columns["index"]), type=pa.int64())})


def write_dataset(root: Path, episodes: list, fps: float = 30.0, version: str = "v3.0", units: str | None = None,
                  names=SO101_NAMES) -> Path:
    """A LeRobot dataset at root: `episodes` a list of (episode_index, values (N, k)) in the dataset's
    units. v3.0: one data file for every episode, meta/episodes/chunk-000/file-000.parquet; v2.1: a
    file per episode, meta/episodes.jsonl. `units` is written into the features' entries when given."""
    import pyarrow as pa
    pq = pyarrow_parquet()
    root = Path(root)
    (root / "meta").mkdir(parents=True, exist_ok=True)
    extra = {"units": units} if units else {}
    meta = info(fps, names, version, **extra)
    meta["total_episodes"] = len(episodes)
    meta["total_frames"] = sum(len(v) for _, v in episodes)
    (root / "meta" / "info.json").write_text(json.dumps(meta, indent=2))
    if version.startswith("v3"):
        (root / "data" / "chunk-000").mkdir(parents=True, exist_ok=True)
        pq.write_table(frames_table(episodes, fps), root / "data" / "chunk-000" / "file-000.parquet")
        (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True, exist_ok=True)
        lengths = [len(v) for _, v in episodes]
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(int) if lengths else []
        pq.write_table(pa.table({"episode_index": pa.array([e for e, _ in episodes], type=pa.int64()),
                                 "length": pa.array(lengths, type=pa.int64()),
                                 "data/chunk_index": pa.array([0] * len(episodes), type=pa.int64()),
                                 "data/file_index": pa.array([0] * len(episodes), type=pa.int64()),
                                 "dataset_from_index": pa.array(list(starts), type=pa.int64()),
                                 "dataset_to_index": pa.array([s + n for s, n in zip(starts, lengths)],
                                                              type=pa.int64())}),
                       root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    else:
        (root / "data" / "chunk-000").mkdir(parents=True, exist_ok=True)
        start = 0
        for e, values in episodes:
            pq.write_table(frames_table([(e, values)], fps, fixed=False, start=start),
                           root / "data" / "chunk-000" / f"episode_{e:06d}.parquet")
            start += len(values)
        (root / "meta" / "episodes.jsonl").write_text(
            "".join(json.dumps({"episode_index": e, "tasks": ["pick"], "length": len(v)}) + "\n" for e, v in episodes))
    return root
