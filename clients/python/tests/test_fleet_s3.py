"""A fleet on an S3 endpoint: moto's S3 server (``moto[server]``, in the ``test`` extra)
stands in for the object store, and two real ``vamos serve`` processes share it through
``[service.shared_store]`` with ``s3://`` (the ``object_store`` crate's S3 client, path-style
requests to ``AWS_ENDPOINT``). A robot, a model and a profile given to the writer reach the
reader without a restart; the reader refuses changes; a deletion reaches it."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

pytest.importorskip("moto")

from _server import ADMIN, ROOT, SIM, Server, free_port, vamos_bin  # noqa: E402
from vamos.client import AdminClient, Conflict  # noqa: E402


@pytest.fixture()
def s3(tmp_path: Path) -> Iterator[str]:
    """moto's S3 server on a free port with an empty bucket ``fleet``; yields its URL."""
    exe = Path(sys.executable).parent / "moto_server"
    if not exe.exists():
        pytest.skip("moto_server is not installed")
    port = free_port()
    log = (tmp_path / "moto.log").open("wb")
    proc = subprocess.Popen([str(exe), "-H", "127.0.0.1", "-p", str(port)], stdout=log, stderr=log)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        try:
            urllib.request.urlopen(urllib.request.Request(f"{url}/fleet", method="PUT"), timeout=5)
            break
        except OSError:
            assert proc.poll() is None, (tmp_path / "moto.log").read_text()
            assert time.monotonic() < deadline, "moto_server did not start"
            time.sleep(0.2)
    yield url
    proc.terminate()
    proc.wait(timeout=30)
    log.close()


def fleet_env(endpoint: str, role: str) -> dict[str, str]:
    return {
        "VAMOS_SERVICE__SHARED_STORE__URL": "s3://fleet/vamos",
        "VAMOS_SERVICE__SHARED_STORE__ROLE": role,
        "VAMOS_SERVICE__SHARED_STORE__POLL_S": "0.2",
        "AWS_ENDPOINT": endpoint,
        "AWS_ALLOW_HTTP": "true",
        "AWS_REGION": "us-east-1",
        "AWS_ACCESS_KEY_ID": "fleet-test",
        "AWS_SECRET_ACCESS_KEY": "fleet-test-secret",
    }


def eventually(check: Callable[[], Any], what: str, timeout: float = 30.0) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        assert time.monotonic() < deadline, what
        time.sleep(0.1)


def test_a_writer_and_a_reader_share_one_s3_store(s3: str, tmp_path: Path) -> None:
    bin = vamos_bin()
    writer = Server(bin, tmp_path / "writer", fleet_env(s3, "writer"))
    reader = Server(bin, tmp_path / "reader", fleet_env(s3, "reader"))
    try:
        w, r = AdminClient(writer.rest, token=ADMIN), AdminClient(reader.rest, token=ADMIN)
        assert r.store_status()["shared_store"]["role"] == "reader"
        w.upload_robot("arm", SIM / "robot" / "vamos_arm.urdf")
        w.upload_model("tiny", ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos")
        camera = json.loads((SIM / "camera.json").read_text())
        w.put_profile("arm-store", {"robot": "arm", "camera": camera, "model": {"name": "tiny"},
                                    "flow_preset": "realtime"})
        eventually(lambda: any(p["name"] == "arm-store" for p in r.profiles()),
                   "the profile never reached the reader")
        assert r.model("tiny")["active"] == 1
        assert [x["name"] for x in r.robots()] == ["arm"]
        status = r.store_status()["shared_store"]
        assert status["generation"] >= 1 and status["last_error"] is None, status
        # What the writer published is in the bucket: a manifest and content-addressed blobs.
        import boto3  # moto's own dependency

        bucket = boto3.client("s3", endpoint_url=s3, region_name="us-east-1",
                              aws_access_key_id="fleet-test", aws_secret_access_key="fleet-test-secret")
        manifest = json.loads(bucket.get_object(Bucket="fleet", Key="vamos/manifest.json")["Body"].read())
        blobs = {o["Key"] for o in bucket.list_objects_v2(Bucket="fleet", Prefix="vamos/blobs/")["Contents"]}
        assert blobs == {f"vamos/blobs/{f['sha256']}" for f in manifest["files"]}
        assert {f["path"] for f in manifest["files"]} >= {
            "models/tiny/1.vamos", "robots/arm/meta.json", "profiles/arm-store/profile.json"}
        with pytest.raises(Conflict):
            r.delete_profile("arm-store")
        w.delete_profile("arm-store")
        eventually(lambda: not any(p["name"] == "arm-store" for p in r.profiles()),
                   "the deletion never reached the reader")
    finally:
        for s in (writer, reader):
            err = s.stop()
            assert "panicked" not in err, err[-4000:]
