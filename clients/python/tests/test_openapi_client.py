"""A client generated from the served OpenAPI document round-trips against the real server.

The server's document is generated from its handlers' Rust types (``vamos openapi`` prints
the same). Here it is validated as OpenAPI 3.0 (openapi-spec-validator), a Python client is
generated from it with openapi-python-client (attrs models, httpx), and that client, not
hand-written code, drives a real ``vamos serve`` (``VAMOS_BIN``; skipped without it):
uploads a robot and a model, writes a profile, reads it back as typed models, patches its
thresholds, scores an episode, and reads every list. What the client sends must come back
equal, and every answer must parse into the generated types, so a handler that writes
something other than its documented type fails here.
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import urllib.request
from pathlib import Path
from typing import Any, Iterator

import pytest

pytest.importorskip("openapi_python_client")
pytest.importorskip("openapi_spec_validator")

from _server import ADMIN, ROOT, SIM, Server, vamos_bin  # noqa: E402

PACKAGE = "vamos_rest_generated"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    s = Server(vamos_bin(), tmp_path_factory.mktemp("openapi-client"))
    yield s
    stderr = s.stop()
    assert s.proc.returncode == 0, stderr[-4000:]
    assert "panicked" not in stderr, stderr[-4000:]


@pytest.fixture(scope="module")
def api(server: Server, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The generated client package, made from the document the server serves."""
    with urllib.request.urlopen(f"{server.rest}/openapi.json", timeout=30) as r:
        doc = json.loads(r.read())
    # The binary prints the document it serves.
    printed = subprocess.run([str(server.bin), "openapi"], capture_output=True, text=True, check=True)
    assert json.loads(printed.stdout) == doc

    from openapi_spec_validator import validate

    validate(doc)
    out = tmp_path_factory.mktemp("generated")
    (out / "openapi.json").write_text(json.dumps(doc))
    bin_dir = Path(sys.executable).parent
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}")
    run = subprocess.run(
        [str(bin_dir / "openapi-python-client"), "generate", "--path", str(out / "openapi.json"),
         "--meta", "none", "--output-path", str(out / PACKAGE)],
        capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-4000:]
    # Every schema became a model: a schema the generator could not read is dropped with a
    # warning naming it (PNG answers are the only content it leaves out).
    warnings = run.stdout + run.stderr
    assert "Unable to process schema" not in warnings, warnings[-4000:]
    sys.path.insert(0, str(out))
    try:
        yield importlib.import_module(PACKAGE)
    finally:
        sys.path.remove(str(out))
        for name in [m for m in sys.modules if m == PACKAGE or m.startswith(PACKAGE + ".")]:
            del sys.modules[name]


def _op(api: Any, name: str) -> Any:
    return importlib.import_module(f"{api.__name__}.api.default.{name}")


def _models(api: Any) -> Any:
    return importlib.import_module(f"{api.__name__}.models")


def _client(api: Any, server: Server) -> Any:
    return api.AuthenticatedClient(base_url=server.rest, token=ADMIN, raise_on_unexpected_status=True)


def test_the_generated_client_round_trips_profiles_models_robots_and_scores(api: Any, server: Server) -> None:
    from vamos_rest_generated.types import File, Unset  # type: ignore[import-not-found]

    m = _models(api)
    client = _client(api, server)

    # Uploads: a URDF robot (query parameter and bytes body) and a model bundle.
    urdf = (SIM / "robot" / "vamos_arm.urdf").read_bytes()
    robot = _op(api, "put_v1_robots_name").sync(
        "arm", client=client, body=File(payload=urdf), format_="urdf")
    assert isinstance(robot, m.RobotInfo), robot
    assert robot.name == "arm" and robot.revision == 1 and len(robot.sha256) == 64
    bundle = (ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos").read_bytes()
    uploaded = _op(api, "put_v1_models_name").sync("tiny", client=client, body=File(payload=bundle))
    assert isinstance(uploaded, m.ModelUploaded), uploaded
    assert uploaded.name == "tiny" and uploaded.version == 1 and uploaded.active == 1

    # A profile written through the generated models comes back equal.
    sent = {
        "robot": "arm",
        "camera": json.loads((SIM / "camera.json").read_text()),
        "model": {"name": "tiny"},
        "flow_preset": "realtime",
        "pipeline": {"stride": 1, "temporal_window": 3,
                     "frames": {"width": 160, "height": 120, "variant": "masked"},
                     "residual": {"flow_pooling": "cells", "flow_cell_px": 8}},
    }
    spec = m.ProfileSpec.from_dict(sent)
    view = _op(api, "put_v1_profiles_name").sync("arm-store", client=client, body=spec)
    assert isinstance(view, m.ProfileView), view
    assert view.source == m.ProfileSource.STORE and isinstance(view.load_error, Unset), view.load_error
    assert view.model == "tiny@1" and view.robot and not view.calibrated
    stored = view.profile
    assert isinstance(stored, m.ProfileInfo)
    back = stored.spec.to_dict()
    assert back["camera"] == sent["camera"] and back["model"] == sent["model"]
    assert back["pipeline"]["frames"]["width"] == 160
    assert back["pipeline"]["residual"]["flow_pooling"] == "cells"
    assert back["pipeline"]["residual"]["flow_cell_px"] == 8
    assert back["pipeline"]["temporal_window"] == 3

    got = _op(api, "get_v1_profiles_name").sync("arm-store", client=client)
    assert isinstance(got, m.ProfileView) and got.profile.spec.to_dict() == back

    # Threshold overrides: a number sets, absent leaves.
    patched = _op(api, "patch_v1_profiles_name_thresholds").sync(
        "arm-store", client=client, body=m.ThresholdsPatch(alarm=2.5, e_c=7.0))
    assert isinstance(patched, m.ProfileView)
    assert patched.alarm_threshold == 2.5
    assert patched.profile.spec.thresholds.e_c == 7.0

    # Lists parse into their types and hold what was written.
    profiles = _op(api, "get_v1_profiles").sync(client=client)
    assert isinstance(profiles, m.ProfileList)
    by_name = {p.name: p for p in profiles.profiles}
    assert by_name["sim-arm"].source == m.ProfileSource.FILE
    assert by_name["arm-store"].profile.spec.to_dict() == patched.profile.spec.to_dict()
    models = _op(api, "get_v1_models").sync(client=client)
    assert [x.name for x in models.models] == ["tiny"] and models.models[0].versions[0].version == 1
    robots = _op(api, "get_v1_robots").sync(client=client)
    assert [x.name for x in robots.robots] == ["arm"]
    metadata = _op(api, "get_v2_models_name").sync("tiny", client=client)
    assert isinstance(metadata, m.ModelMetadata) and metadata.platform == "vamos_bundle"
    assert metadata.versions == ["1"] and metadata.inputs[0].name == "flow"
    whoami = _op(api, "get_v1_whoami").sync(client=client)
    assert whoami.role == m.Role.ADMIN and whoami.tokens is True
    store = _op(api, "get_v1_store").sync(client=client)
    assert isinstance(store, m.StoreStatus) and store.problems == 0

    # An episode scored through the generated client: typed scores, one per frame.
    episode = (SIM / "test" / "test_0000.mcap").read_bytes()
    scores = _op(api, "post_v1_episodesscore").sync(
        client=client, body=File(payload=episode), profile="sim-arm", name="rt")
    assert isinstance(scores, m.EpisodeScores), scores
    assert scores.damage is None
    offline = server.offline(SIM / "test" / "test_0000.mcap")
    assert [f.stamp_ns for f in scores.frames] == [f["stamp_ns"] for f in offline]
    assert [f.score for f in scores.frames] == pytest.approx([f["score"] for f in offline], rel=1e-9)

    # Errors are typed too.
    missing = _op(api, "get_v1_profiles_name").sync_detailed("no-such-profile", client=_client(api, server))
    assert missing.status_code == 404
    assert isinstance(missing.parsed, m.ErrorBody) and "no-such-profile" in missing.parsed.error

    # Clean-up through the client: 204s.
    for op, name in [("delete_v1_profiles_name", "arm-store"), ("delete_v1_models_name", "tiny"),
                     ("delete_v1_robots_name", "arm")]:
        assert _op(api, op).sync_detailed(name, client=client).status_code == 204
