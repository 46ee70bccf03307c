"""Schemathesis fuzzing of the real ``vamos serve`` REST API from its own OpenAPI document.

The server is started once (``VAMOS_BIN``; skipped without it) and seeded with a robot, a
model and a stored profile, so generated requests also reach existing objects. Then the
schemathesis CLI runs every operation of the document the server serves at
``GET /openapi.json`` (but that one, which schemathesis does not fuzz: it loads it) with all
its phases (coverage, fuzzing, stateful; valid and invalid data), twice:

* with the admin token: no answer may be a 5xx;
* without a token: no 5xx either, and every request that reaches a route needing a token
  must be answered 401 (schemathesis sends some requests without an ``Authorization``
  header and some with made-up ones).

After each run the server process must still be alive and ready. Runs are reproducible:
one worker and a fixed seed. ``VAMOS_FUZZ_EXAMPLES`` (default 15 per operation) and
``VAMOS_FUZZ_SEED`` change the volume and the seed.
"""

from __future__ import annotations

import collections
import json
import os
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional
from urllib.parse import urlsplit

import pytest

pytest.importorskip("schemathesis")

from _server import ADMIN, ROOT, SIM, Server, vamos_bin  # noqa: E402

EXAMPLES = int(os.environ.get("VAMOS_FUZZ_EXAMPLES", "15"))
SEED = int(os.environ.get("VAMOS_FUZZ_SEED", "20261201"))
#: What the seeded server holds; the generated names, profiles and versions are drawn
#: from these about half of the time.
ROBOT_NAME, MODEL_NAME, STORED_PROFILE, FILE_PROFILE = "arm", "tiny", "arm-store", "sim-arm"
#: The operation that serves the document schemathesis loads (it is not fuzzed).
SCHEMA_OPERATION = "GET /openapi.json"
METHODS = ("get", "put", "post", "delete", "patch", "head", "options", "trace")


def _call(server: Server, method: str, path: str, body: Optional[bytes] = None,
          content_type: Optional[str] = None, token: Optional[str] = ADMIN) -> tuple[int, bytes]:
    """One HTTP request to the server's REST port: ``(status, body)``."""
    req = urllib.request.Request(server.rest + path, data=body, method=method)
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    if content_type:
        req.add_header("Content-Type", content_type)
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def _seed(server: Server) -> None:
    """Stores a robot, a model and a profile that uses both."""
    urdf = (SIM / "robot" / "vamos_arm.urdf").read_bytes()
    status, text = _call(server, "PUT", f"/v1/robots/{ROBOT_NAME}?format=urdf", urdf)
    assert status == 201, text
    bundle = (ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos").read_bytes()
    status, text = _call(server, "PUT", f"/v1/models/{MODEL_NAME}", bundle, "application/octet-stream")
    assert status == 201, text
    spec = {"robot": ROBOT_NAME, "camera": json.loads((SIM / "camera.json").read_text()),
            "model": {"name": MODEL_NAME}, "flow_preset": "realtime",
            "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120, "variant": "masked"}}}
    status, text = _call(server, "PUT", f"/v1/profiles/{STORED_PROFILE}", json.dumps(spec).encode(),
                         "application/json")
    assert status == 200, text
    assert json.loads(text).get("load_error") is None, text


def _config(path: Path) -> Path:
    """A schemathesis config file that draws names from the seeded objects half the time."""
    names = [ROBOT_NAME, MODEL_NAME, STORED_PROFILE, FILE_PROFILE]
    path.write_text(
        "[dictionaries.names]\n"
        f"values = {json.dumps(names)}\n"
        "[dictionaries.robots]\n"
        f"values = {json.dumps([ROBOT_NAME])}\n"
        "[dictionaries.models]\n"
        f"values = {json.dumps([MODEL_NAME])}\n"
        "[dictionaries.versions]\n"
        "values = [1]\n"
        "[parameters]\n"
        '"path.name" = { dictionary = "names", probability = 0.5 }\n'
        '"query.profile" = { dictionary = "names", probability = 0.5 }\n'
        '"path.version" = { dictionary = "versions", probability = 0.5 }\n'
        '"body.version" = { dictionary = "versions", probability = 0.5 }\n'
        '"body.robot" = { dictionary = "robots", probability = 0.5 }\n'
        '"body.model.name" = { dictionary = "models", probability = 0.5 }\n')
    return path


@dataclass
class Exchange:
    """One request schemathesis sent and the answer it got."""

    #: Schemathesis's label: the operation (``"GET /v1/models"``), or ``"Stateful tests"``.
    operation: str
    method: str
    path: str
    #: Whether the request had an ``Authorization`` header.
    authorization: bool
    #: ``None``: no answer (the connection failed).
    status: Optional[int]


@dataclass
class Run:
    """The outcome of one schemathesis run."""

    returncode: int
    output: str = field(repr=False)
    report: dict[str, Any] = field(repr=False)
    exchanges: list[Exchange] = field(default_factory=list, repr=False)
    seconds: float = 0.0

    def summary(self) -> str:
        """Operations, test cases, requests, status classes and failures, on one line."""
        statuses = collections.Counter(
            f"{e.status // 100}xx" if e.status else "none" for e in self.exchanges)
        return (f"{self.report['operations']['tested']}/{self.report['operations']['total']} operations, "
                f"{self.report['test_cases']['generated']} test cases, {len(self.exchanges)} requests "
                f"({dict(sorted(statuses.items()))}), {len(self.report['failures'])} failures, "
                f"{self.seconds:.1f} s")


def _exchanges(ndjson: Path) -> list[Exchange]:
    """Every request of a run, from the NDJSON event report."""
    out = []
    for line in ndjson.read_text().splitlines():
        recorder = json.loads(line).get("ScenarioFinished", {}).get("recorder", {})
        for interaction in recorder.get("interactions", {}).values():
            request, response = interaction["request"], interaction.get("response") or {}
            out.append(Exchange(
                operation=recorder["label"], method=request["method"].upper(),
                path=urlsplit(request["uri"]).path,
                authorization=any(k.lower() == "authorization" for k in request.get("headers", {})),
                status=response.get("status_code")))
    return out


#: What every answer must show: no 5xx, and (with the admin token, when requests reach the
#: handlers) a status, a content type and a body that the document describes for that
#: operation: the document is generated from the handlers' types, and this holds them to it.
CHECKS = "not_a_server_error"
CONFORMANCE = "status_code_conformance,content_type_conformance,response_schema_conformance"


def _schemathesis(server: Server, out: Path, token: Optional[str], checks: str = CHECKS) -> Run:
    """The schemathesis CLI over the served OpenAPI document, reports in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    args = [sys.executable, "-m", "schemathesis.cli", "--no-color",
            "--config-file", str(_config(out / "schemathesis.toml")),
            "run", f"{server.rest}/openapi.json",
            "--checks", checks,
            "--max-examples", str(EXAMPLES), "--seed", str(SEED), "--workers", "1",
            "--generation-database", "none", "--request-timeout", "60",
            "--report", "json,ndjson", "--report-dir", str(out),
            "--report-json-path", str(out / "report.json"), "--report-ndjson-path", str(out / "events.ndjson")]
    if token:
        args += ["--header", f"Authorization: Bearer {token}"]
    started = time.monotonic()
    # The working directory is `out` so that no schemathesis.toml of a parent folder applies.
    run = subprocess.run(args, cwd=out, capture_output=True, text=True, timeout=900)
    seconds = time.monotonic() - started
    output = run.stdout + run.stderr
    assert (out / "report.json").exists(), output[-4000:]
    return Run(run.returncode, output, json.loads((out / "report.json").read_text()),
               _exchanges(out / "events.ndjson"), seconds)


def _operations(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The served document's operations by schemathesis label (``"GET /path"``)."""
    return {f"{m.upper()} {path}": op for path, item in doc["paths"].items()
            for m, op in item.items() if m in METHODS}


def _route(template: str) -> re.Pattern[str]:
    """A regular expression of the request paths a route template matches."""
    parts = re.split(r"(\{[^}]+\})", template)
    return re.compile("".join("[^/]+" if p.startswith("{") else re.escape(p) for p in parts) + "$")


def _routed(exchange: Exchange, routes: dict[str, re.Pattern[str]]) -> Optional[str]:
    """The operation the server routes a request to, as the router does: its method and a
    path that the route's template matches (an empty parameter, or one holding an
    unescaped ``/``, is another path). ``None``: no route (404 or 405)."""
    for label, pattern in routes.items():
        method, _ = label.split(" ", 1)
        if exchange.method == method and pattern.match(exchange.path):
            return label
    return None


def _check(server: Server, run: Run, operations: dict[str, dict[str, Any]]) -> None:
    """What every run must show: every operation tested and answered, no 5xx, and a
    server that is still alive and ready."""
    print(f"\nschemathesis: {run.summary()}")
    assert server.proc.poll() is None, f"the server exited during the run:\n{server.stderr()[-4000:]}"
    assert server.ready(), "the server is not ready after the run"
    assert run.returncode == 0 and not run.report["failures"] and not run.report["errors"], (
        f"schemathesis failed (exit {run.returncode}):\n{run.output[-8000:]}")
    server_errors = [e for e in run.exchanges if e.status is not None and e.status >= 500]
    assert not server_errors, server_errors[:20]
    # Schemathesis leaves out the operation that serves the document it loaded.
    expected = set(operations) - {SCHEMA_OPERATION}
    assert run.report["operations"]["tested"] == len(expected), run.report["operations"]
    answered = {e.operation for e in run.exchanges if e.status is not None}
    assert expected <= answered, f"never answered: {sorted(expected - answered)}"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A seeded server for the whole module; it must stop cleanly afterwards."""
    s = Server(vamos_bin(), tmp_path_factory.mktemp("rest-fuzz"))
    try:
        _seed(s)
    except BaseException:
        s.stop()
        raise
    yield s
    stderr = s.stop()
    assert s.proc.returncode == 0, stderr[-4000:]
    assert "panicked" not in stderr, stderr[-4000:]


@pytest.fixture(scope="module")
def operations(server: Server) -> dict[str, dict[str, Any]]:
    """The operations of the document the server serves."""
    status, text = _call(server, "GET", "/openapi.json", token=None)
    assert status == 200, text
    ops = _operations(json.loads(text))
    assert len(ops) > 20
    return ops


def test_fuzz_with_the_admin_token(server: Server, operations: dict[str, dict[str, Any]],
                                   tmp_path: Path) -> None:
    run = _schemathesis(server, tmp_path / "admin", ADMIN, f"{CHECKS},{CONFORMANCE}")
    _check(server, run, operations)
    # The token was used: requests got past the access check.
    assert any(e.status is not None and e.status < 400 for e in run.exchanges
               if e.operation == "GET /v1/sessions")


def test_fuzz_without_a_token(server: Server, operations: dict[str, dict[str, Any]],
                              tmp_path: Path) -> None:
    run = _schemathesis(server, tmp_path / "anonymous", None)
    _check(server, run, operations)
    secured = {label for label, op in operations.items() if op.get("security") != []}
    assert secured and all(operations[label].get("x-vamos-role") for label in secured)
    routes = {label: _route(label.split(" ", 1)[1]) for label in operations}
    refused: collections.Counter[str] = collections.Counter()
    without_header = 0
    answered = []
    for e in run.exchanges:
        label = _routed(e, routes)
        if label not in secured:
            continue
        if e.status == 401:
            refused[label] += 1
            without_header += not e.authorization
        else:
            answered.append((label, e))
    assert not answered, f"answered without a token: {answered[:20]}"
    assert set(refused) == secured, f"never refused: {sorted(secured - set(refused))}"
    assert without_header > 0, "every request carried an Authorization header"
