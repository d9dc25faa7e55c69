"""LeRobot datasets read with pyarrow alone (the `lerobot` extra; never the `lerobot` package, whose
dynamixel-sdk pin conflicts with servodyn's): `read_dataset(DIR)` gives each episode's frames of one
feature (`action`, or `observation.state`) with their `names` and the dataset's fps.

Both layouts LeRobot writes (../shared/notes/lerobot.md §2.2):

  v3.0  meta/info.json; data/chunk-XXX/file-XXX.parquet, many episodes a file;
        meta/episodes/chunk-XXX/file-XXX.parquet, one row an episode (its `length`)
  v2.x  meta/info.json; data/chunk-XXX/episode_XXXXXX.parquet, one episode a file;
        meta/episodes.jsonl, one line an episode (its `length`)

Every data parquet carries `episode_index`, `frame_index` and `timestamp` beside the features, so the
episodes are found in the rows themselves whatever the layout; the episodes' metadata, where present,
is checked against them (an episode listed with no frames is refused: an empty episode). Videos are
not read. Every fault of a dataset is one line, a `DatasetError` (exit 2), naming the file."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

FEATURES = ("action", "observation.state")       # the joint-position vectors a dataset records
NEEDED = ("episode_index", "frame_index")        # the columns every data file must have besides the feature


class DatasetError(InputError):
    """A LeRobot dataset that cannot be validated: one line naming the file and what is wrong (exit 2)."""


def pyarrow_parquet():
    """pyarrow.parquet, or one line saying how to install it."""
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise DatasetError("reading a LeRobot dataset needs pyarrow: pip install 'servodyn[lerobot]' "
                           "(or pip install pyarrow)") from None
    return pq


@dataclass
class Episode:
    index: int
    t: np.ndarray            # (N,) s: the frames' timestamps (frame_index / fps where absent)
    values: np.ndarray       # (N, k) the feature, in the dataset's units
    source: str              # the file its frames came from (the first, for an episode split across files)


@dataclass
class Dataset:
    root: Path
    version: str             # codebase_version, e.g. "v3.0"
    fps: float
    feature: str             # "action" or "observation.state"
    names: list              # the feature's names, e.g. "shoulder_pan.pos"
    info: dict               # meta/info.json
    episodes: list           # Episode, by index

    @property
    def units_declared(self) -> str | None:
        """The units the feature's entry in meta/info.json states (`"units": "degrees"` or
        `"range_m100_100"`), None when it states none (LeRobot's own datasets do not)."""
        units = self.info["features"][self.feature].get("units")
        return units if isinstance(units, str) else None


def _fail(where, message: str):
    raise DatasetError(f"{where}: {message}")


def read_info(root: Path) -> dict:
    """meta/info.json, checked for what the reader needs: fps and features."""
    path = root / "meta" / "info.json"
    if not root.is_dir():
        _fail(root, "no such dataset folder")
    try:
        info = json.loads(path.read_text())
    except FileNotFoundError:
        _fail(root, "no meta/info.json: not a LeRobot dataset (v2.1 or v3.0)")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        _fail(path, f"not readable JSON ({err})")
    if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
        _fail(path, "has no 'features' table")
    fps = info.get("fps")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
        _fail(path, f"'fps' must be a positive number, got {fps!r}")
    return info


def feature_names(info: dict, feature: str, path: Path) -> list:
    """The feature's names from meta/info.json: a list, or (LeRobot v2.0) a table with one list
    (`{"motors": [...]}`), as long as its shape says."""
    entry = info["features"].get(feature)
    if not isinstance(entry, dict):
        have = ", ".join(k for k in FEATURES if k in info["features"]) or "neither"
        _fail(path, f"no feature '{feature}' (this dataset has {have} of {' and '.join(FEATURES)})")
    names = entry.get("names")
    if isinstance(names, dict) and len(names) == 1:
        names = next(iter(names.values()))
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        _fail(path, f"feature '{feature}' has no list of 'names' (one a joint, e.g. \"shoulder_pan.pos\")")
    shape = entry.get("shape")
    if isinstance(shape, list) and shape and shape[0] != len(names):
        _fail(path, f"feature '{feature}' has {len(names)} names for shape {shape}")
    return names


def data_files(root: Path) -> list[Path]:
    files = sorted((root / "data").glob("**/*.parquet"))
    if not files:
        _fail(root, "no data/**/*.parquet files")
    return files


def _read_table(pq, path: Path, feature: str):
    """The columns the reader needs from one data file; one line for a file that is no parquet or
    lacks one of them."""
    try:
        schema = pq.read_schema(path)
    except Exception as err:            # pyarrow's ArrowInvalid / OSError: not a parquet file
        _fail(path, f"not a readable parquet file ({str(err).splitlines()[0] if str(err) else type(err).__name__})")
    missing = [c for c in (feature, *NEEDED) if c not in schema.names]
    if missing:
        _fail(path, f"missing column '{missing[0]}' (it has {', '.join(schema.names)})")
    columns = [feature, *NEEDED] + (["timestamp"] if "timestamp" in schema.names else [])
    try:
        return pq.read_table(path, columns=columns)
    except Exception as err:
        _fail(path, f"not a readable parquet file ({str(err).splitlines()[0] if str(err) else type(err).__name__})")


def _vectors(column, width: int, path: Path, feature: str) -> np.ndarray:
    """A list column as (N, width) floats: every row `width` long, no null, every value finite."""
    import pyarrow as pa
    import pyarrow.compute as pc
    column = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    if not (pa.types.is_list(column.type) or pa.types.is_large_list(column.type)
            or pa.types.is_fixed_size_list(column.type)):
        _fail(path, f"column '{feature}' holds {column.type}, not a vector a frame")
    if column.null_count:
        _fail(path, f"column '{feature}': row {int(np.argmax(column.is_null().to_numpy(zero_copy_only=False)))} is null")
    lengths = pc.list_value_length(column).to_numpy(zero_copy_only=False)
    ragged = np.flatnonzero(lengths != width)
    if ragged.size:
        r = int(ragged[0])
        _fail(path, f"column '{feature}' is ragged: row {r} has {int(lengths[r])} values, its names {width}")
    flat = column.flatten()
    if flat.null_count:
        _fail(path, f"column '{feature}' has a null value")
    values = flat.to_numpy(zero_copy_only=False).astype(float).reshape(len(column), width)
    bad = ~np.isfinite(values)
    if bad.any():
        r, j = map(int, np.argwhere(bad)[0])
        _fail(path, f"column '{feature}': row {r}, value {j} is {values[r, j]} (not a finite number)")
    return values


def listed_lengths(root: Path) -> dict:
    """episode_index -> length from the episodes' metadata (v3.0: meta/episodes/**/*.parquet; v2.x:
    meta/episodes.jsonl); {} when the dataset has neither."""
    lengths = {}
    jsonl = root / "meta" / "episodes.jsonl"
    if jsonl.is_file():
        for n, line in enumerate(jsonl.read_text().splitlines(), start=1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                lengths[int(row["episode_index"])] = int(row["length"])
            except (ValueError, KeyError, TypeError):
                _fail(jsonl, f"line {n} is not an episode with 'episode_index' and 'length'")
    pq = None
    for path in sorted((root / "meta" / "episodes").glob("**/*.parquet")):
        pq = pq or pyarrow_parquet()
        try:
            table = pq.read_table(path, columns=["episode_index", "length"])
        except Exception as err:
            _fail(path, f"not a parquet file of episodes with 'episode_index' and 'length' ({str(err).splitlines()[0]})")
        for index, length in zip(table.column("episode_index").to_pylist(), table.column("length").to_pylist()):
            lengths[int(index)] = int(length)
    return lengths


def read_dataset(root, feature: str = "action", episodes=None) -> Dataset:
    """The dataset at `root`: each episode's frames of `feature` (in `episodes` when given, else
    every one), in frame order. DatasetError for anything malformed (see the module's docstring)."""
    root = Path(root)
    if feature not in FEATURES:
        raise DatasetError(f"feature must be one of {', '.join(FEATURES)}, got '{feature}'")
    info = read_info(root)
    info_path = root / "meta" / "info.json"
    names = feature_names(info, feature, info_path)
    fps = float(info["fps"])
    pq = pyarrow_parquet()
    frames: dict[int, list] = {}
    for path in data_files(root):
        table = _read_table(pq, path, feature)
        values = _vectors(table.column(feature), len(names), path, feature)
        index = np.asarray(table.column("episode_index").to_numpy(zero_copy_only=False), dtype=np.int64)
        frame = np.asarray(table.column("frame_index").to_numpy(zero_copy_only=False), dtype=np.int64)
        stamp = (np.asarray(table.column("timestamp").to_numpy(zero_copy_only=False), dtype=float)
                 if "timestamp" in table.column_names else frame / fps)
        if not np.all(np.isfinite(stamp)):
            _fail(path, f"column 'timestamp': row {int(np.argmax(~np.isfinite(stamp)))} is not a finite number")
        for e in np.unique(index):
            rows = index == e
            frames.setdefault(int(e), []).append((frame[rows], stamp[rows], values[rows], path))
    listed = listed_lengths(root)
    wanted = sorted(set(frames) | set(listed)) if episodes is None else list(episodes)
    unknown = [e for e in wanted if e not in frames and e not in listed]
    if unknown:
        _fail(root, f"no episode {unknown[0]} (it has {_ranges(sorted(set(frames) | set(listed)))})")
    read = [_episode(e, frames.get(e, []), listed.get(e), root, fps) for e in wanted]
    return Dataset(root=root, version=str(info.get("codebase_version", "")), fps=fps, feature=feature,
                   names=names, info=info, episodes=read)


def _episode(index: int, parts: list, listed: int | None, root: Path, fps: float) -> Episode:
    if not parts or sum(len(p[0]) for p in parts) == 0:
        _fail(root, f"episode {index} is empty (no frames in data/)")
    frame = np.concatenate([p[0] for p in parts])
    order = np.argsort(frame, kind="stable")
    frame = frame[order]
    t = np.concatenate([p[1] for p in parts])[order]
    values = np.concatenate([p[2] for p in parts])[order]
    source = str(parts[0][3])
    if listed is not None and listed != len(frame):
        _fail(source, f"episode {index} has {len(frame)} frames; the episodes' metadata lists {listed}")
    if np.any(np.diff(frame) <= 0):
        _fail(source, f"episode {index}: frame {int(frame[np.argmax(np.diff(frame) <= 0)])} appears twice")
    if len(frame) < 2:
        _fail(source, f"episode {index} has one frame: a motion needs two")
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0)) + 1
        _fail(source, f"episode {index}: timestamp {t[k]:g} s at frame {int(frame[k])} does not increase")
    return Episode(index=index, t=t - t[0], values=values, source=source)


def _ranges(indices: list) -> str:
    """Episode indices as "0-49" or "0, 2, 5" (for a message)."""
    if not indices:
        return "no episodes"
    if indices == list(range(indices[0], indices[-1] + 1)) and len(indices) > 2:
        return f"episodes {indices[0]}-{indices[-1]}"
    return "episodes " + ", ".join(map(str, indices[:10])) + (" ..." if len(indices) > 10 else "")
