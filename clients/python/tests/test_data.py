"""Dataset reading, episode split, time-agnostic pair sampling."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vamos.train.data import DatasetError, PairSampler, load_dataset, split_episodes


def write_labelled_dataset(root: Path, lengths: list[int]) -> Path:
    """Episodes whose rows are constant ``1000 * episode + row``, so a row names itself."""
    root.mkdir(parents=True, exist_ok=True)
    entries = []
    for e, length in enumerate(lengths):
        rows = (1000.0 * e + np.arange(length, dtype=np.float32))[:, None, None, None]
        np.save(root / f"e{e}.npy", np.broadcast_to(rows, (length, 2, 8, 8)).astype(np.float32))
        entries.append({"name": f"e{e}", "file": f"e{e}.npy",
                        "frames": [{"index": i, "stamp_ns": i} for i in range(length)]})
    manifest = {"format": "vamos-dataset", "format_version": 1,
                "input": {"size": 8, "clip_px": 15.0, "reference_width_px": 640},
                "flow_variant": "masked", "processing": {"width": 640, "height": 480, "stride": 3},
                "episodes": entries}
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


def test_load_dataset_reads_contract(tiny_dataset: Path) -> None:
    ds = load_dataset(tiny_dataset)
    assert [e.name for e in ds.episodes] == [f"ep{i:04d}" for i in range(5)]
    assert ds.input_size == 64
    ep = ds.episodes[0]
    assert ep.flows.shape == (14, 2, 64, 64) and ep.flows.dtype == np.float32
    assert isinstance(ep.flows, np.memmap)
    assert float(np.abs(ep.flows).max()) <= 0.5


def test_load_dataset_rejects_bad_input(tmp_path: Path) -> None:
    root = write_labelled_dataset(tmp_path / "d", [12, 12])
    manifest = json.loads((root / "manifest.json").read_text())
    bad = dict(manifest, format_version=2)
    (root / "manifest.json").write_text(json.dumps(bad))
    with pytest.raises(DatasetError, match="format_version"):
        load_dataset(root)
    # Frame count that disagrees with the array.
    manifest["episodes"][0]["frames"] = manifest["episodes"][0]["frames"][:-1]
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="expected C-order float32"):
        load_dataset(root)
    with pytest.raises(DatasetError, match="cannot read"):
        load_dataset(tmp_path / "missing")


def test_sampler_draws_uniform_offsets_within_episodes(tmp_path: Path) -> None:
    root = write_labelled_dataset(tmp_path / "d", [12, 30, 9, 20])  # 9 rows: no valid target
    ds = load_dataset(root)
    a, b = 5, 4
    sampler = PairSampler(ds.episodes, a, b)
    assert len(sampler) == (12 - 9) + (30 - 9) + 0 + (20 - 9)
    counts = np.zeros(a + b + 1, dtype=np.int64)
    rng = np.random.default_rng(0)
    for _ in range(400):
        plan = sampler.plan(rng)
        # Every valid target exactly once per epoch.
        pairs = sorted(zip(plan.episode.tolist(), plan.target.tolist(), strict=True))
        expected = sorted((e, t) for e, ep in enumerate(ds.episodes) for t in range(a + b, ep.length))
        assert pairs == expected
        past, target = sampler.gather(plan, 0, len(plan))
        past_v, target_v = past[:, 0, 0, 0], target[:, 0, 0, 0]
        # Same episode (same thousands), n = target row - past row in {a..a+b}.
        assert np.array_equal(np.floor(past_v / 1000), np.floor(target_v / 1000))
        n = (target_v - past_v).astype(np.int64)
        assert n.min() >= a and n.max() <= a + b
        assert np.array_equal(n, plan.target - plan.past)
        counts += np.bincount(n, minlength=a + b + 1)
    observed = counts[a:]
    assert counts[:a].sum() == 0
    # 400 epochs x 35 samples = 14000 draws over 5 values: each ~2800 (sd ~47).
    expected = observed.sum() / (b + 1)
    assert np.all(np.abs(observed - expected) < 5 * np.sqrt(expected)), observed


def test_sampler_is_seeded() -> None:
    lengths = [15, 15]
    from vamos.train.data import Episode

    eps = [Episode(name=str(i), flows=np.zeros((n, 2, 8, 8), np.float32), frames=[]) for i, n in enumerate(lengths)]
    s = PairSampler(eps, 5, 4)
    p1, p2 = s.plan(np.random.default_rng(3)), s.plan(np.random.default_rng(3))
    assert np.array_equal(p1.past, p2.past) and np.array_equal(p1.target, p2.target)
    assert not np.array_equal(p1.past, s.plan(np.random.default_rng(4)).past)


def test_split_by_episode() -> None:
    names = [f"ep{i}" for i in range(20)]
    train, val = split_episodes(names, 0.25, seed=1)
    assert len(val) == 5 and len(train) == 15
    assert set(train).isdisjoint(val) and set(train) | set(val) == set(names)
    assert (train, val) == split_episodes(names, 0.25, seed=1)
    assert val != split_episodes(names, 0.25, seed=2)[1]
    # Order of the input list does not change which episodes are chosen.
    assert set(split_episodes(list(reversed(names)), 0.25, seed=1)[1]) == set(val)
    # A tiny fraction still holds one episode out; zero holds none.
    assert len(split_episodes(names, 0.01, seed=1)[1]) == 1
    assert split_episodes(names, 0.0, seed=1) == (names, [])
    # Explicit lists.
    rest = [n for n in names if n not in ("ep1", "ep3")]
    assert split_episodes(names, 0.5, 0, val_names=["ep3", "ep1"]) == (rest, ["ep1", "ep3"])
    with pytest.raises(DatasetError, match="unknown"):
        split_episodes(names, 0.5, 0, val_names=["nope"])
    with pytest.raises(DatasetError, match="both"):
        split_episodes(names, 0.5, 0, val_names=["ep1"], train_names=["ep1", "ep2"])
