"""Real robot descriptions load: ``vamos robot inspect`` on every URDF of two public
collections, example-robot-data (PyPI ``example-robot-data``, the ``test`` extra) and
pybullet_data (shipped with ``pybullet``, the ``sim`` extra).

Every URDF must load (exit status 0, one JSON object) except the few listed in
``REFUSED``, each with the reason (urdfdom, the ROS parser, refuses them too). What
vamos drops while loading (an unreadable mesh, a tolerated construct) is a warning in the
output, not a failure. A listed file that starts loading fails the test too, so the list
stays true.

Needs the ``vamos`` binary: ``VAMOS_BIN`` names it (``scripts/test.sh`` sets it); skipped
without it, or without the collection's package.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

#: URDFs vamos refuses (path relative to the collection's root -> why). (A mimic of a
#: joint that does not exist, as in alex_psyonic_hands.urdf, loads with a warning.)
REFUSED: dict[str, dict[str, str]] = {
    "example-robot-data": {
        "robots/ur_description/urdf/ur3.urdf": "an empty <robot> (no links; a xacro left-over)",
    },
    "pybullet_data": {
        "bicycle/bike.urdf": 'comma-separated vectors (xyz="0.07, 0, -0.69")',
        "biped/biped2d_pybullet.urdf":
            'limit lower="-1.57." is not a number (and the XML declaration is not at the start)',
        "husky/husky.urdf": 'unexpanded xacro expressions (xyz="$(optenv HUSKY_IMU_XYZ 0.19 0 0.149)")',
        "quadruped/microtaur/microtaur.urdf": 'a joint origin rpy of 4 values ("-3.14159 1.57079 0 0")',
        "spherical_joint_limit.urdf": "a <limit> without velocity (on a spherical joint, a type urdfdom lacks)",
        "torus_deform.urdf": "a deformable body (<deformable>), no <link>",
    },
}

#: URDFs that load with a mesh vamos cannot parse (-> why); every other mesh that exists
#: must parse (binary STL files whose header starts with "solid", OBJ files mixing face
#: formats, ...). Meshes that are not there at all are warnings, not checked here.
UNREADABLE_MESH: dict[str, dict[str, str]] = {
    "example-robot-data": {},
    "pybullet_data": {"random_urdfs/168/168.urdf": "168.obj has a non-finite vertex (nan)"},
}


def _vamos_bin() -> Path:
    value = os.environ.get("VAMOS_BIN")
    if not value:
        pytest.skip("VAMOS_BIN is not set (scripts/test.sh sets it)")
    path = Path(value)
    assert path.is_file(), f"VAMOS_BIN={value} does not exist"
    return path


def _example_robot_data() -> "tuple[Path, list[Path]]":
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed (the test extra installs it)")
    urdfs = sorted(Path(str(f.locate())) for f in files if str(f).endswith(".urdf"))
    assert urdfs, "example-robot-data ships no .urdf files"
    # <prefix>/share/example-robot-data/robots/<name>_description/...
    root = next(p for p in urdfs[0].parents if p.name == "example-robot-data")
    return root, urdfs


def _pybullet_data() -> "tuple[Path, list[Path]]":
    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or spec.origin is None:
        pytest.skip("pybullet_data is not installed (the sim extra's pybullet installs it)")
    root = Path(spec.origin).parent
    urdfs = sorted(root.rglob("*.urdf"))
    assert urdfs, f"{root} holds no .urdf files"
    return root, urdfs


def _inspect(bin: Path, urdf: Path, env: "dict[str, str]") -> "tuple[int, str, str]":
    proc = subprocess.run(
        [str(bin), "robot", "inspect", "--robot", str(urdf)],
        capture_output=True, text=True, env=env, timeout=120,
    )
    return proc.returncode, proc.stdout, proc.stderr


@pytest.mark.parametrize("collection", sorted(REFUSED))
def test_every_urdf_of_the_collection_loads(collection: str) -> None:
    bin = _vamos_bin()
    root, urdfs = _example_robot_data() if collection == "example-robot-data" else _pybullet_data()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
    env["VAMOS_LOG__LEVEL"] = "error"
    # Each process loads one robot (meshes in parallel inside); a few at a time overlap
    # process start-up and file reads.
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        results = list(pool.map(lambda u: _inspect(bin, u, env), urdfs))
    refused = REFUSED[collection]
    failed: dict[str, str] = {}
    unreadable: dict[str, str] = {}
    loaded = 0
    for urdf, (rc, out, err) in zip(urdfs, results):
        rel = urdf.relative_to(root).as_posix()
        if rc != 0:
            # A refusal is a clean one-line error, never a crash.
            assert rc == 1 and "panicked" not in err, f"{rel}: exit {rc}\n{err}"
            failed[rel] = err.strip().splitlines()[-1] if err.strip() else "(no message)"
            continue
        report = json.loads(out)
        assert report["links"], f"{rel}: no links"
        loaded += 1
        bad = [w for w in report["warnings"] if "is unreadable" in w]
        if bad:
            unreadable[rel] = bad[0]
    unexpected = {k: v for k, v in failed.items() if k not in refused}
    assert not unexpected, f"{len(unexpected)} of {len(urdfs)} refused:\n" + "\n".join(
        f"  {k}: {v}" for k, v in sorted(unexpected.items()))
    now_loading = sorted(set(refused) - set(failed))
    assert not now_loading, f"listed in REFUSED but load now: {now_loading}"
    assert loaded == len(urdfs) - len(refused)
    assert sorted(unreadable) == sorted(UNREADABLE_MESH[collection]), "\n".join(
        f"  {k}: {v}" for k, v in sorted(unreadable.items()))
