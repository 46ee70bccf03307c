"""``vamos-client``: replay bags as live robots, score episodes, administer a server.

    vamos-client stream BAG.mcap --profile P [--server 127.0.0.1:8081] [--rate 1.0 | --fast] [--anomaly-maps DIR]
    vamos-client score BAG.mcap --profile P
    vamos-client models list | upload NAME FILE | activate NAME VERSION [--reload-sessions] | delete NAME
    vamos-client robots list | upload NAME PATH | delete NAME
    vamos-client profiles list | get NAME | put NAME SPEC.json | delete NAME | nominal NAME
    vamos-client thresholds PROFILE [--e-c X] [--e-b X] [--alarm X] (or "none" to clear)
    vamos-client calibrate PROFILE EPISODE... [--holdout EPISODE...] [--alpha 0.1] [--server-paths] [--no-wait]
    vamos-client alarms list [--session ID] [--profile P] [--marked] | get ID | mark ID [--note TEXT]
                        | thumbnail ID FILE.png
    vamos-client recalibrate PROFILE [--apply] [--no-wait] [--timeout S]
    vamos-client jobs [ID] [--cancel | --apply]
    vamos-client sessions [--reload ID]

Scores, events and alarm events are printed as JSON lines on stdout, everything else as
JSON; a summary goes to stderr. The token comes from --token, else VAMOS_TOKEN, else the
first of VAMOS_ADMIN_TOKEN: listing alarms takes any token, marking a false alarm a robot
token (of the session's robot) or an admin token, recalibrating an admin token. Exit
codes: 0 done, 1 an error the server reported, 2 bad usage.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Optional, Sequence

from ._types import AlarmEvent, FrameScore, SessionEvent, VamosError
from .._cli import add_version
from .admin import AdminClient, token_from_env


def _print(v: Any) -> None:
    print(json.dumps(v, sort_keys=True), flush=True)


def _update_json(u: Any) -> dict[str, Any]:
    if isinstance(u, FrameScore):
        return {"type": "score", **u.to_dict()}
    if isinstance(u, SessionEvent):
        return {"type": "event", **u.to_dict()}
    if isinstance(u, AlarmEvent):
        return {"type": "alarm", **u.to_dict()}
    return {"type": "unknown"}


class _MapWriter:
    """Writes each score's anomaly map to ``DIR/<stem>_<frame>.png`` and names the file in
    the score's JSON line."""

    def __init__(self, folder: Optional[str], stem: str) -> None:
        self.folder = Path(folder) if folder else None
        self.stem = stem
        self.written = 0
        if self.folder is not None:
            self.folder.mkdir(parents=True, exist_ok=True)

    def line(self, u: Any) -> dict[str, Any]:
        out = _update_json(u)
        if self.folder is not None and isinstance(u, FrameScore) and u.anomaly_map:
            path = self.folder / f"{self.stem}_{u.frame:06d}.png"
            path.write_bytes(u.anomaly_map)
            out["anomaly_map"] = str(path)
            self.written += 1
        return out


def _threshold(text: str) -> Optional[float]:
    if text.lower() in ("none", "null", "clear"):
        return None
    return float(text)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vamos-client", description=(__doc__ or "").split("\n\n")[0])
    add_version(p)
    p.add_argument("--server", default="127.0.0.1:8081", help="gRPC address (default %(default)s)")
    p.add_argument("--api", default="http://127.0.0.1:8080", help="REST address (default %(default)s)")
    p.add_argument("--token", default=None, help="bearer token (default: $VAMOS_TOKEN)")
    p.add_argument("--ca", default=None, help="PEM CA certificate for TLS servers")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("stream", help="replay a bag as a live robot and print every score, event and alarm")
    s.add_argument("episode", help="the recorded episode (ROS 2 bag, .mcap)")
    s.add_argument("--profile", required=True, help="the server's profile to score with")
    pace = s.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, help="recorded pace x this (default 1.0)")
    pace.add_argument("--fast", action="store_true", help="as fast as the server scores")
    s.add_argument("--window", type=int, default=4, help="images unanswered with --fast (default 4)")
    s.add_argument("--session-id", default=None, help="default: the bag's file stem")
    s.add_argument("--robot-id", default="vamos-client", help="the robot's name in the session (default %(default)s)")
    s.add_argument("--anomaly-maps", metavar="DIR", default=None,
                   help="ask for anomaly maps and write each as DIR/<session>_<frame>.png (named in its score's line)")

    s = sub.add_parser("score", help="upload a bag whole and print every frame's score")
    s.add_argument("episode", help="the recorded episode (ROS 2 bag, .mcap)")
    s.add_argument("--profile", required=True, help="the server's profile to score with")

    s = sub.add_parser("models", help="stored models")
    ms = s.add_subparsers(dest="action", required=True, metavar="ACTION")
    ms.add_parser("list", help="every model with its versions")
    x = ms.add_parser("upload", help="upload a bundle as the model's next version")
    x.add_argument("name", help="model name")
    x.add_argument("file", help="model bundle (.vamos)")
    x = ms.add_parser("activate", help="make a version the active one")
    x.add_argument("name", help="model name")
    x.add_argument("version", type=int, help="version number")
    x.add_argument("--reload-sessions", action="store_true", help="move running sessions too")
    x = ms.add_parser("delete", help="delete a model, or one of its versions")
    x.add_argument("name", help="model name")
    x.add_argument("--version", type=int, default=None, help="only this version (default: the whole model)")

    s = sub.add_parser("robots", help="stored robots")
    rs = s.add_subparsers(dest="action", required=True, metavar="ACTION")
    rs.add_parser("list", help="every stored robot")
    x = rs.add_parser("upload", help="upload a robot description")
    x.add_argument("name", help="robot name")
    x.add_argument("path", help="URDF, .tar.gz, .zip or a package folder")
    x = rs.add_parser("delete", help="delete a robot")
    x.add_argument("name", help="robot name")

    s = sub.add_parser("profiles", help="stored profiles")
    ps = s.add_subparsers(dest="action", required=True, metavar="ACTION")
    ps.add_parser("list", help="every stored profile")
    for action, text in (("get", "print a profile"), ("delete", "delete a profile")):
        x = ps.add_parser(action, help=text)
        x.add_argument("name", help="profile name")
    x = ps.add_parser("put", help="create or replace a profile")
    x.add_argument("name", help="profile name")
    x.add_argument("spec", help="ProfileSpec JSON file")
    x = ps.add_parser("nominal", help="the profile's nominal set (recordings kept by false-alarm marks)")
    x.add_argument("name", help="profile name")

    s = sub.add_parser("thresholds", help="override a profile's thresholds")
    s.add_argument("profile", help="profile name")
    for flag in ("--e-c", "--e-b", "--alarm"):
        s.add_argument(flag, type=_threshold, default=argparse.SUPPRESS, help="a number, or none to clear")

    s = sub.add_parser("calibrate", help="calibrate a stored profile on nominal episodes")
    s.add_argument("profile", help="profile name")
    s.add_argument("episodes", nargs="+", help="nominal episodes (.mcap) to calibrate on")
    s.add_argument("--holdout", nargs="*", default=[], help="nominal episodes held out for the conformal threshold")
    s.add_argument("--alpha", type=float, default=0.1, help="false-alarm rate of the threshold (default %(default)s)")
    s.add_argument("--server-paths", action="store_true", help="the episodes are paths on the server")
    s.add_argument("--no-wait", action="store_true", help="print the job id and return")

    s = sub.add_parser("alarms", help="alarms and false-alarm marks")
    als = s.add_subparsers(dest="action", required=True, metavar="ACTION")
    x = als.add_parser("list", help="the recent alarms, newest first (or the stored false alarms)")
    x.add_argument("--session", default=None, help="only this session's alarms")
    x.add_argument("--profile", default=None, help="only alarms of sessions on this profile")
    x.add_argument("--marked", action="store_true", help="the stored false alarms instead (oldest mark first)")
    x = als.add_parser("get", help="print one alarm")
    x.add_argument("id", help="alarm id (al-...)")
    x = als.add_parser("mark", help="mark an alarm as a false alarm (robot or admin token)")
    x.add_argument("id", help="alarm id (al-...)")
    x.add_argument("--note", default="", help="why it is a false alarm (kept with the mark; at most 500 characters)")
    x = als.add_parser("thumbnail", help="save the frame at the alarm's start (PNG)")
    x.add_argument("id", help="alarm id (al-...)")
    x.add_argument("file", help="where to write the PNG")

    s = sub.add_parser("recalibrate", help="recalibrate a stored profile from its false alarms (admin token)")
    s.add_argument("profile", help="profile name")
    s.add_argument("--apply", action="store_true", help="apply the proposal once the job has succeeded")
    s.add_argument("--no-wait", action="store_true", help="print the job id and return")
    s.add_argument("--timeout", type=float, default=3600.0, help="seconds to wait for the job (default %(default)s)")

    s = sub.add_parser("jobs", help="calibration and recalibration jobs")
    s.add_argument("id", nargs="?", type=int, help="a job id (default: list every job)")
    job_action = s.add_mutually_exclusive_group()
    job_action.add_argument("--cancel", action="store_true", help="cancel the job (or forget a finished one)")
    job_action.add_argument("--apply", action="store_true", help="apply a finished recalibration's proposal")

    s = sub.add_parser("sessions", help="sessions open now")
    s.add_argument("--reload", metavar="ID", default=None, help="move session ID to its profile as stored now")
    return p


#: The parser, for documentation and tests.
build_parser = _parser


def _run(args: argparse.Namespace) -> int:
    token = args.token or token_from_env()
    ca = open(args.ca, "rb").read() if args.ca else None
    if args.command in ("stream", "score"):
        from .monitor import MonitorClient

        with MonitorClient(args.server, token=token, root_certificates=ca) as client:
            if args.command == "score":
                n = 0
                for s in client.iter_score_episode(args.episode, args.profile):
                    _print(_update_json(s))
                    n += 1
                print(f"{n} frames scored", file=sys.stderr)
                return 0
            maps = _MapWriter(args.anomaly_maps, args.session_id or Path(args.episode).stem)
            summary = client.replay(args.episode, args.profile, rate=None if args.fast else args.rate,
                                    window=args.window, session_id=args.session_id,
                                    robot_id=args.robot_id, anomaly_maps=args.anomaly_maps is not None,
                                    on_update=lambda u: _print(maps.line(u)))
            anomalies = sum(1 for s in summary.scores if s.anomaly)
            started = sum(1 for a in summary.alarms if a.started)
            print(f"session {summary.session_id}: {summary.images_sent} images sent, "
                  f"{len(summary.scores)} scored, {anomalies} anomalous, {started} alarm(s), "
                  f"{summary.dropped} dropped, {len(summary.message_errors)} refused, "
                  f"{summary.reconnects} reconnects, {summary.elapsed_s:.1f} s"
                  + (f", {maps.written} anomaly map(s) in {args.anomaly_maps}" if args.anomaly_maps else ""),
                  file=sys.stderr)
            return 0
    admin = AdminClient(args.api, token=token, ca_file=args.ca)
    cmd, action = args.command, getattr(args, "action", None)
    if cmd == "models":
        if action == "list":
            _print(admin.models())
        elif action == "upload":
            _print(admin.upload_model(args.name, args.file))
        elif action == "activate":
            _print(admin.activate_model(args.name, args.version, reload_sessions=args.reload_sessions))
        else:
            admin.delete_model(args.name, args.version)
    elif cmd == "robots":
        if action == "list":
            _print(admin.robots())
        elif action == "upload":
            _print(admin.upload_robot(args.name, args.path))
        else:
            admin.delete_robot(args.name)
    elif cmd == "profiles":
        if action == "list":
            _print(admin.profiles())
        elif action == "get":
            _print(admin.profile(args.name))
        elif action == "put":
            with open(args.spec) as fh:
                _print(admin.put_profile(args.name, json.load(fh)))
        elif action == "nominal":
            _print(admin.nominal(args.name))
        else:
            admin.delete_profile(args.name)
    elif cmd == "thresholds":
        given = {k: getattr(args, k) for k in ("e_c", "e_b", "alarm") if hasattr(args, k)}
        if not given:
            print("error: give at least one of --e-c, --e-b, --alarm", file=sys.stderr)
            return 2
        _print(admin.set_thresholds(args.profile, **given))
    elif cmd == "calibrate":
        job = admin.calibrate(args.profile, args.episodes, args.holdout, alpha=args.alpha,
                              upload=not args.server_paths)
        if args.no_wait:
            _print({"job": job})
        else:
            print(f"calibration job {job} started; waiting", file=sys.stderr)
            _print(admin.wait_job(job))
    elif cmd == "alarms":
        if action == "list":
            _print(admin.alarms(session=args.session, profile=args.profile, marked=args.marked))
        elif action == "get":
            _print(admin.alarm(args.id))
        elif action == "mark":
            _print(admin.mark_false_alarm(args.id, args.note))
        else:
            png = admin.alarm_thumbnail(args.id)
            Path(args.file).write_bytes(png)
            print(f"{len(png)} bytes written to {args.file}", file=sys.stderr)
    elif cmd == "recalibrate":
        job = admin.recalibrate(args.profile)
        if args.no_wait:
            _print({"job": job})
            return 0
        print(f"recalibration job {job} started; waiting", file=sys.stderr)
        record = admin.wait_job(job, timeout=args.timeout)
        if args.apply:
            record = admin.apply_job(job)
            print(f"job {job}'s proposal applied to {args.profile}", file=sys.stderr)
        _print(record)
    elif cmd == "jobs":
        if args.id is None:
            if args.cancel or args.apply:
                print("error: --cancel and --apply need a job id", file=sys.stderr)
                return 2
            _print(admin.jobs())
        elif args.cancel:
            _print({"job": args.id, "cancelling": admin.cancel_job(args.id)})
        elif args.apply:
            _print(admin.apply_job(args.id))
        else:
            _print(admin.job(args.id))
    elif cmd == "sessions":
        _print(admin.reload_session(args.reload) if args.reload else admin.sessions())
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of ``vamos-client``; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        return _run(args)
    except (VamosError, OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
