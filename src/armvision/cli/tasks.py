"""``armvision demo``, ``grab``, ``analyze``, ``follow`` and ``ui``: the tasks on a running
system, simulated or real, and their parsers."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from armvision.cli.args import (
    _say,
    _sim_calibration_path,
    _where,
    arm_option,
    out_dir,
    port,
    runs,
    seconds,
    seed,
    tag_id,
    track_id,
    writable_dir,
)
from armvision.cli.evaluate import cmd_eval_follow, cmd_eval_grab, cmd_eval_sort
from armvision.cli.record import add_record_option, finish_recording, record_system
from armvision.config import Config
from armvision.errors import ArmvisionError

if TYPE_CHECKING:
    from armvision.runtime.system import System

#: Seconds the stages run before a task starts, so tracks are confirmed and tags seen.
WARM_UP_S = 1.5


def cmd_demo(args: argparse.Namespace, config: Config) -> int:
    from armvision.bench.demo import run_demo

    writable_dir(args.out)  # before the calibration and the run, not after them
    report = run_demo(
        config, args.seed, args.out, args.calibration, say=_say, record_to=args.record
    )
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        print(report.table())
        if report.image_path is not None:
            print(f"annotated image: {report.image_path}")
    return 0 if report.ok else 1


def _system(args: argparse.Namespace, config: Config):
    """The System the task commands run on (see the module docstring)."""
    from armvision.runtime import build

    if args.real:
        return build.real_system(config, args.calibration or config.calibration.file)
    from armvision.bench.system import calibrate_empty_table, sim_system
    from armvision.sim.scene import generate_scene

    if args.calibration == "truth":
        calibration = None  # the simulator's camera pose
    elif args.calibration:
        calibration = build.load_calibration(args.calibration)
    else:
        _say("calibrating the simulated camera with the gripper tag (empty table)")
        T_base_cam = generate_scene(config, args.seed).T_base_cam
        calibration, _ = calibrate_empty_table(config, args.seed, T_base_cam)
    mode: Literal["lockstep", "realtime"] = "realtime" if args.realtime else "lockstep"
    return sim_system(config, args.seed, mode=mode, calibration=calibration)


def _run(
    args: argparse.Namespace,
    config: Config,
    name: str,
    fn,
    before: tuple[str, Any, dict[str, Any]] | None = None,
    **kwargs: Any,
) -> int:
    """Run task ``name`` (after the task ``before``, if given: its failure is the result)."""
    system = _system(args, config)
    recorder = record_system(args.record, config, system)
    with system:
        if system.lockstep:
            system.pump(system.clock() + WARM_UP_S)
        else:
            time.sleep(WARM_UP_S)
        try:
            status = None
            if before is not None:
                _say(f"running {before[0]}" + (" (Ctrl-C stops it)" if not system.lockstep else ""))
                status = system.run_task(before[0], before[1], **before[2])
                if status.phase == "succeeded":
                    status = None
            if status is None:
                _say(f"running {name}" + (" (Ctrl-C stops it)" if not system.lockstep else ""))
                status = system.run_task(name, fn, **kwargs)
        except KeyboardInterrupt:
            system.stop_task()
            _say("stopped: the arm holds where it is")
            raise
        truth = _sim_truth(system) if not args.real else None
    finish_recording(recorder)
    report = {"task": status.to_dict(), "truth": truth}
    if args.json:
        print(json.dumps(report, indent=2, default=float))
    else:
        print(f"{name}: {status.phase}" + (f" ({status.error})" if status.error else ""))
        for key, value in (status.result or {}).items():
            print(f"  {key:<16} {value}")
        if truth:
            print("simulator truth:")
            for key, value in truth.items():
                print(f"  {key:<16} {value}")
    return 0 if status.phase == "succeeded" else 1


def _sim_truth(system: System) -> dict[str, Any]:
    from armvision.bench.system import sim_world

    world = sim_world(system)
    return {
        "held_object": world.held_object(),
        "objects": [
            {
                "name": o.spec.name,
                "kind": o.spec.kind,
                "label": o.spec.label,
                "position": [round(float(v), 4) for v in o.T_base_obj[:3, 3]],
                "fill": round(o.spec.fill, 4),
                "liquid": o.spec.liquid,
            }
            for o in world.objects()
        ],
    }


def cmd_grab(args: argparse.Namespace, config: Config) -> int:
    from armvision.tasks.grab import grab

    return _run(args, config, "grab", grab, track_id=args.track)


def cmd_analyze(args: argparse.Namespace, config: Config) -> int:
    from armvision.tasks.analyze import analyze

    return _run(args, config, "analyze", analyze, track_id=args.track)


def cmd_place(args: argparse.Namespace, config: Config) -> int:
    """Grab a bottle (``--track``, else the grab's choice), then place it: the place task
    sets down what a grab holds, and a fresh system holds nothing."""
    from armvision.tasks.grab import grab
    from armvision.tasks.place import place, zone_rect

    spot = args.x is not None or args.y is not None
    if args.zone is not None and spot:
        raise ArmvisionError("give --zone NAME or --x and --y (metres), not both")
    if args.zone is None and (args.x is None or args.y is None):
        raise ArmvisionError("say where: --zone NAME, or --x and --y (metres)")
    if args.zone is not None:
        zone_rect(config, args.zone)  # an unknown zone fails before the system is built
    kwargs = {"zone": args.zone} if args.zone is not None else {"x": args.x, "y": args.y}
    return _run(
        args, config, "place", place, before=("grab", grab, {"track_id": args.track}), **kwargs
    )


def cmd_sort(args: argparse.Namespace, config: Config) -> int:
    from armvision.tasks.sort import SortRule, sort

    rule: dict[str, Any] | None = None
    if args.threshold is not None:
        rule = {"threshold": args.threshold}
    if args.colours is not None:
        rule = {}
        for part in args.colours.split(","):
            name, sep, zone = part.partition("=")
            if not sep or not name.strip() or not zone.strip():
                raise ArmvisionError(
                    f"--colours {args.colours!r}: write NAME=ZONE pairs, e.g. "
                    "'light blue=empty,*=full'"
                )
            rule[name.strip()] = zone.strip()
    by = args.by or ("colour" if args.colours is not None else None)
    SortRule.make(config, by, rule)  # a bad rule fails before the system is built
    return _run(args, config, "sort", sort, by=by, rule=rule)


def cmd_follow(args: argparse.Namespace, config: Config) -> int:
    from armvision.tasks.follow import follow

    return _run(
        args,
        config,
        "follow",
        follow,
        target=args.target,
        tag_id=args.tag_id,
        track_id=args.track,
        duration_s=args.duration,
        mode=args.mode,
    )


def cmd_ui(args: argparse.Namespace, config: Config) -> int:

    from armvision.ui.server import OperatorUI, Server, listen, resolve_token

    host = args.host or config.ui.host
    port = config.ui.port if args.port is None else args.port
    token = resolve_token(host, config.ui.token)
    sock = listen(host, port)  # a busy port fails before the system is built
    if args.real:
        saved_to = args.calibration or config.calibration.file
        if not Path(saved_to).exists():
            _say(f"no calibration at {saved_to}: the page's Calibrate makes one (clear the table)")
    else:
        saved_to = str(_sim_calibration_path(config.calibration.file))
        # A tag on the table for Follow tag (loose tags get ids 0, 1, ...: follow.tag_id 0).
        config = dataclasses.replace(
            config, sim=dataclasses.replace(config.sim, loose_tags=max(config.sim.loose_tags, 1))
        )
        args.realtime = True
    try:
        if args.real:
            from armvision.runtime.build import real_system

            system = real_system(config, saved_to, allow_uncalibrated=True)
        else:
            system = _system(args, config)
    except BaseException:
        sock.close()
        raise
    try:
        recorder = _ui_recorder(args.record, config, system)
    except BaseException:
        sock.close()
        system.close()
        raise
    with system:
        ui = OperatorUI(system, config, "real" if args.real else "sim", token, saved_to)
        ui.recording = recorder
        server = Server(ui, sock)
        _say(f"operator UI at {server.url()}  (Ctrl-C quits; the arm halts where it is)")
        try:
            server.run()  # until Ctrl-C (uvicorn then re-raises it: exit status 130)
        finally:
            _say("UI closing: stopping the threads")
    finish_recording(ui.recording)  # the newest: from --record or the page's Record
    _say("UI closed")
    return 0


def _ui_recorder(path: str | None, config: Config, system: System):
    """The UI's recorder: to ``--record``'s file, and live to Foxglove with ``ui.foxglove``
    (then it runs all along, and Record / Stop recording start and finish its files)."""
    if not config.ui.foxglove:
        return record_system(path, config, system)
    from armvision.recording.live import LiveServer
    from armvision.runtime.recorder import Recorder, RecordingError

    live = LiveServer(config.ui.foxglove_host, config.ui.foxglove_port)
    _say(f"Foxglove live view at {live.url()} (Foxglove: Open connection, Foxglove WebSocket)")
    try:
        recorder = Recorder(path, config, wait=False, notify=_say, live=live).open()
    except RecordingError as exc:
        _say(f"{exc}; the run goes on without recording")
        recorder = Recorder(None, config, wait=False, notify=_say, live=live).open()
    system.attach_recorder(recorder)
    return recorder


def _trial_options(parser: argparse.ArgumentParser, trials: int) -> None:
    """The options of an evaluation over random scenes run as task trials (grab, sort)."""
    parser.add_argument("--trials", type=runs, default=trials, help=f"scenes (default {trials})")
    parser.add_argument("--seed", type=seed, default=0, help="first scene seed (default 0)")
    parser.add_argument(
        "--calibration",
        choices=("calibrate", "truth"),
        default="calibrate",
        help="calibrate once with the tag (default) or use the simulator's camera pose",
    )


def add_parsers(sub: Any, eval_sub: Any) -> None:
    """Add the demo, task and task-eval commands to ``armvision``'s parsers."""
    demo = sub.add_parser(
        "demo", help="the whole system on a simulated scene, with a report against the truth"
    )
    demo.add_argument("--seed", type=seed, default=0, help="scene seed (default 0)")
    demo.add_argument(
        "--out", type=out_dir, default="out/demo", metavar="DIR", help="where the image goes"
    )
    demo.add_argument("--calibration", metavar="PATH", help="load this instead of calibrating")
    demo.add_argument("--json", action="store_true", help="the report as JSON")
    add_record_option(demo)
    arm_option(demo)
    demo.set_defaults(func=cmd_demo)

    grab = sub.add_parser("grab", help="grasp a bottle and lift it")
    _where(grab)
    grab.add_argument("--track", type=track_id, help="bottle track id (default: nearest reachable)")
    add_record_option(grab)
    grab.set_defaults(func=cmd_grab)

    analyze = sub.add_parser("analyze", help="measure a bottle's liquid level")
    _where(analyze)
    analyze.add_argument("--track", type=track_id, help="bottle track id (default: nearest)")
    add_record_option(analyze)
    analyze.set_defaults(func=cmd_analyze)

    place = sub.add_parser(
        "place", help="grab a bottle and set it down at a spot or on a free spot of a zone"
    )
    _where(place)
    place.add_argument("--track", type=track_id, help="bottle track id (default: the grab's)")
    place.add_argument("--zone", help="a zone of place.zones (default zones: empty, full)")
    place.add_argument("--x", type=float, help="spot x, metres, base frame")
    place.add_argument("--y", type=float, help="spot y, metres, base frame")
    add_record_option(place)
    place.set_defaults(func=cmd_place)

    sort = sub.add_parser("sort", help="sort the bottles on the table into zones by fill or colour")
    _where(sort)
    sort.add_argument("--by", choices=("fill", "colour"), help="default sort.by (fill)")
    sort.add_argument(
        "--threshold", type=float, help="fill 0..1 below which a bottle goes to sort.below"
    )
    sort.add_argument(
        "--colours",
        metavar="NAME=ZONE,...",
        help="by colour: colour name to zone, '*' for any other (default sort.colours)",
    )
    add_record_option(sort)
    sort.set_defaults(func=cmd_sort)

    follow = sub.add_parser("follow", help="follow a tag or a bottle with the gripper")
    _where(follow)
    follow.add_argument("--target", choices=("tag", "bottle"), default="tag")
    follow.add_argument("--tag-id", type=tag_id, help="tag to follow (default follow.tag_id)")
    follow.add_argument("--track", type=track_id, help="bottle track id (default: nearest)")
    follow.add_argument("--duration", type=seconds, help="seconds (default follow.duration_s)")
    follow.add_argument("--mode", choices=("servo", "blocking"), default="servo")
    add_record_option(follow)
    follow.set_defaults(func=cmd_follow)

    ui = sub.add_parser("ui", help="the operator web UI: live video, state, every task")
    _where(
        ui,
        task=False,
        calibration_help="calibration file (real default: calibration.file; Calibrate saves "
        "there); in simulation the default is to calibrate at start, and 'truth' uses the "
        "simulator's pose",
    )
    ui.add_argument(
        "--host",
        help="address to listen on (default ui.host, 127.0.0.1); any other needs the token "
        "that is printed (or ui.token / $ARMVISION_UI_TOKEN)",
    )
    ui.add_argument("--port", type=port, help="port 0-65535 (default ui.port, 8000)")
    add_record_option(ui)
    ui.set_defaults(func=cmd_ui)

    grab_eval = eval_sub.add_parser("grab", help="grasp success over random scenes")
    _trial_options(grab_eval, trials=50)
    grab_eval.add_argument("--jobs", type=runs, default=1, help="trials at a time (processes)")
    grab_eval.add_argument("--json", action="store_true", help="one JSON object on stdout")
    arm_option(grab_eval)
    grab_eval.set_defaults(func=cmd_eval_grab)

    sort_eval = eval_sub.add_parser("sort", help="sorting bottles by fill over random sort scenes")
    _trial_options(sort_eval, trials=20)
    sort_eval.add_argument("--jobs", type=runs, default=1, help="trials at a time (processes)")
    sort_eval.add_argument("--json", action="store_true", help="one JSON object on stdout")
    arm_option(sort_eval)
    sort_eval.set_defaults(func=cmd_eval_sort)

    follow_eval = eval_sub.add_parser("follow", help="servo vs blocking tag following")
    follow_eval.add_argument("--seed", type=seed, default=0)
    follow_eval.add_argument("--duration", type=seconds, help="seconds per mode")
    follow_eval.add_argument("--json", action="store_true", help="one JSON object on stdout")
    follow_eval.set_defaults(func=cmd_eval_follow)
