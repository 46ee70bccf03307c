"""Training datasets (``vamos export-dataset`` output), episode split and pair sampling.

Time-agnostic sampling: a training sample is a pair ``(O_{t-n}, O_t)`` of rows of one
episode's array, with ``n`` drawn uniformly from ``{a, ..., a + b}``. The valid targets of
an episode with ``T`` rows are ``t = a + b, ..., T - 1`` (every ``n`` is possible for every
valid target, so ``n`` is exactly uniform and independent of ``t``; pairs never cross
episodes). An epoch visits every valid target of the training episodes exactly once, in a
random order, with a fresh ``n`` for each. Episodes with ``T <= a + b`` give no samples.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: ``format`` of a dataset manifest.
DATASET_FORMAT = "vamos-dataset"
#: Newest dataset ``format_version`` this reader knows.
DATASET_FORMAT_VERSION = 1
#: Allowed ``flow_variant`` values.
FLOW_VARIANTS = ("plain", "registered", "masked", "masked_registered")


class DatasetError(ValueError):
    """A dataset directory does not follow the contract."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


@dataclass(frozen=True)
class Episode:
    """One episode: its name, its flow rows (memory-mapped ``[T, 2, S, S]``) and frame info."""

    name: str
    flows: np.ndarray
    frames: list[dict[str, Any]]

    @property
    def length(self) -> int:
        """Number of flow rows ``T``."""
        return int(self.flows.shape[0])


@dataclass(frozen=True)
class FlowDataset:
    """A dataset directory read per the contract."""

    path: Path
    manifest: dict[str, Any]
    episodes: list[Episode] = field(repr=False)

    @property
    def input_size(self) -> int:
        """Side ``S`` of the square network input."""
        return int(self.manifest["input"]["size"])

    def episode(self, name: str) -> Episode:
        """Episode by name."""
        for episode in self.episodes:
            if episode.name == name:
                return episode
        raise DatasetError(self.path, f"no episode named {name!r}")


def load_dataset(path: str | Path) -> FlowDataset:
    """Read and validate ``path/manifest.json`` and memory-map every episode's ``.npy``.

    Checks the format and version, the flow variant, that every array is float32 C-order
    ``[T, 2, S, S]`` with ``S = input.size`` and ``T = len(frames)``, and that names are unique.
    """
    root = Path(path)
    manifest_path = root / "manifest.json"
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except OSError as err:
        raise DatasetError(root, f"cannot read manifest.json ({err})") from err
    except json.JSONDecodeError as err:
        raise DatasetError(root, f"manifest.json is not valid JSON ({err})") from err
    if not isinstance(manifest, dict) or manifest.get("format") != DATASET_FORMAT:
        raise DatasetError(root, f"manifest format is not {DATASET_FORMAT!r}")
    version = manifest.get("format_version")
    if not isinstance(version, int) or not 1 <= version <= DATASET_FORMAT_VERSION:
        raise DatasetError(root, f"format_version {version!r} unsupported (known: 1..{DATASET_FORMAT_VERSION})")
    try:
        size = int(manifest["input"]["size"])
        float(manifest["input"]["clip_px"])
        int(manifest["input"]["reference_width_px"])
        processing = manifest["processing"]
        int(processing["width"]), int(processing["height"]), int(processing["stride"])
        entries = manifest["episodes"]
    except (KeyError, TypeError, ValueError) as err:
        raise DatasetError(root, f"manifest misses or mistypes a field ({err!r})") from err
    if manifest.get("flow_variant") not in FLOW_VARIANTS:
        raise DatasetError(root, f"flow_variant {manifest.get('flow_variant')!r} is not one of {FLOW_VARIANTS}")
    if not isinstance(entries, list) or not entries:
        raise DatasetError(root, "manifest lists no episodes")
    episodes = []
    seen: set[str] = set()
    for entry in entries:
        try:
            name, file, frames = str(entry["name"]), str(entry["file"]), list(entry["frames"])
        except (KeyError, TypeError) as err:
            raise DatasetError(root, f"episode entry {entry!r} lacks name, file or frames") from err
        if name in seen:
            raise DatasetError(root, f"episode name {name!r} appears twice")
        seen.add(name)
        file_path = root / file
        if Path(file).is_absolute() or ".." in Path(file).parts:
            raise DatasetError(root, f"episode {name}: file {file!r} must be relative to the dataset")
        try:
            flows = np.load(file_path, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError) as err:
            raise DatasetError(root, f"episode {name}: cannot load {file} ({err})") from err
        expected = (len(frames), 2, size, size)
        if flows.dtype != np.float32 or flows.shape != expected or not flows.flags.c_contiguous:
            raise DatasetError(
                root,
                f"episode {name}: {file} is {flows.dtype} {flows.shape}, expected C-order float32 {expected}",
            )
        episodes.append(Episode(name=name, flows=flows, frames=frames))
    return FlowDataset(path=root, manifest=manifest, episodes=episodes)


def split_episodes(
    names: list[str],
    val_fraction: float,
    seed: int,
    val_names: list[str] | None = None,
    train_names: list[str] | None = None,
) -> tuple[list[str], list[str]]:
    """Split episode names into ``(train, validation)``.

    With ``val_names`` the split is explicit (``train_names`` defaults to the rest).
    Otherwise ``round(val_fraction * E)`` episodes (at least 1 when ``val_fraction > 0``)
    are chosen by a permutation of the sorted names seeded with ``seed``; the training set
    always keeps at least one episode. Both lists come back in dataset order.
    """
    known = set(names)
    if val_names is not None or train_names is not None:
        val = list(val_names or [])
        train = list(train_names) if train_names is not None else [n for n in names if n not in set(val)]
        unknown = [n for n in val + train if n not in known]
        if unknown:
            raise DatasetError("<split>", f"unknown episodes {unknown}")
        overlap = sorted(set(val) & set(train))
        if overlap:
            raise DatasetError("<split>", f"episodes in both train and validation: {overlap}")
    else:
        count = int(round(val_fraction * len(names)))
        if val_fraction > 0:
            count = max(count, 1)
        count = min(count, len(names) - 1)
        order = np.random.default_rng([seed, 0x5EED]).permutation(len(names))
        ordered = sorted(names)
        val_set = {ordered[i] for i in order[:count]}
        val = [n for n in names if n in val_set]
        train = [n for n in names if n not in val_set]
    if not train:
        raise DatasetError("<split>", "no training episodes")
    return [n for n in names if n in set(train)], [n for n in names if n in set(val)]


@dataclass(frozen=True)
class PairBatchPlan:
    """One epoch's samples: parallel arrays of episode index, past row and target row."""

    episode: np.ndarray
    past: np.ndarray
    target: np.ndarray

    def __len__(self) -> int:
        return int(self.target.shape[0])


class PairSampler:
    """Draws time-agnostic ``(O_{t-n}, O_t)`` pairs from a list of episodes (see module doc)."""

    def __init__(self, episodes: list[Episode], a: int, b: int) -> None:
        if a < 1 or b < 0:
            raise ValueError(f"need a >= 1 and b >= 0, got a={a}, b={b}")
        self.episodes = episodes
        self.a = a
        self.b = b
        episode_idx: list[np.ndarray] = []
        targets: list[np.ndarray] = []
        for i, episode in enumerate(episodes):
            t = np.arange(a + b, episode.length, dtype=np.int64)
            episode_idx.append(np.full(t.shape, i, dtype=np.int64))
            targets.append(t)
        self._episode = np.concatenate(episode_idx) if episode_idx else np.zeros(0, np.int64)
        self._target = np.concatenate(targets) if targets else np.zeros(0, np.int64)

    def __len__(self) -> int:
        """Number of valid targets (samples per epoch)."""
        return int(self._target.shape[0])

    def plan(self, rng: np.random.Generator, shuffle: bool = True) -> PairBatchPlan:
        """One epoch: every valid target once (shuffled if asked), each with a fresh ``n``."""
        order = rng.permutation(len(self)) if shuffle else np.arange(len(self))
        n = rng.integers(self.a, self.a + self.b + 1, size=len(self))
        target = self._target[order]
        return PairBatchPlan(episode=self._episode[order], past=target - n, target=target)

    def gather(self, plan: PairBatchPlan, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``start:stop`` of a plan as ``(past, target)`` float32 arrays ``[B, 2, S, S]``."""
        rows = range(start, min(stop, len(plan)))
        past = np.stack([self.episodes[plan.episode[i]].flows[plan.past[i]] for i in rows])
        target = np.stack([self.episodes[plan.episode[i]].flows[plan.target[i]] for i in rows])
        return past, target
