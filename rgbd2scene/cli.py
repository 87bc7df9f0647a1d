"""Command line: ``rgbd2scene <command>`` (CONVENTIONS §5).

User errors print one line ``error: ...`` on stderr and exit with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from rgbd2scene.errors import RenderError, UserError


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line error format."""

    def error(self, message: str):
        self.exit(2, f"error: {self.prog}: {message} (see --help)\n")


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` for argparse (the one definition is :func:`rgbd2scene.stages.render.parse_size`)."""
    from rgbd2scene.stages.render import parse_size as parse

    try:
        return parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _add_capture_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("capture (an RGB-D frame, several frames to fuse, or a stereo frame)")
    g.add_argument("--rgb", nargs="+", help="colour image(s) (PNG, JPEG, PPM, BMP); several frames are fused")
    g.add_argument("--depth", nargs="+", help="depth: 16-bit PNG, float EXR/.npy (m), NYU raw PGM, SUN PNG; "
                   "one per --rgb")
    g.add_argument("--poses", help="camera trajectory of the frames: TUM (timestamp tx ty tz qx qy qz qw) or "
                   "Redwood/Open3D .log; default: estimated by RGB-D odometry")
    cam = g.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera JSON: {width,height,fx,fy,cx,cy} or Open3D intrinsic_matrix")
    cam.add_argument("--preset", help="named camera: primesense (default), kinect_v1, tum_fr1, tum_fr2, tum_fr3")
    g.add_argument("--depth-scale", type=float, help="depth units per metre (1000 for mm PNG, 5000 for TUM)")
    g.add_argument("--depth-format", default="auto", help="auto, png, sun, nyu, exr, npy")
    g.add_argument("--left", help="left image of a stereo endoscope frame")
    g.add_argument("--right", help="right image of the stereo frame")
    g.add_argument("--stereo-calib", help="stereo calibration: JSON (K_left, D_left, K_right, D_right, R, T in "
                   "metres, image_size) or a Hamlyn-style folder (calib.left.intrinsic.txt, ..., calib.l2r.4x4 in mm)")
    from rgbd2scene.options import add_arguments
    from rgbd2scene.reconstruct.pipeline import MeshOptions

    add_arguments(p.add_argument_group("reconstruction"), MeshOptions)
    f = p.add_argument_group("fusion of several frames")
    f.add_argument("--voxel-size", type=float, help="TSDF voxel edge in metres (default 1.5 pixel footprints at "
                   "the first frame's median depth)")
    f.add_argument("--min-frames", type=int, help="keep surface seen by at least this many frames (default 1)")
    s = p.add_argument_group("stereo")
    s.add_argument("--matcher", default="auto", choices=("auto", "sgbm", "elas"),
                   help="stereo matcher (default auto: ELAS when pyelas is installed, else SGBM)")
    s.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"),
                   help="expected depth range in metres; sets the disparities searched (default 0.02 0.5)")


def _has_capture_input(args) -> bool:
    return any(getattr(args, name) for name in ("rgb", "depth", "left", "right", "stereo_calib"))


def _check_inputs(args) -> str:
    """The input mode ("rgbd", "fusion" or "stereo") of the capture arguments, or a one-line UserError
    (also when options of another mode are given: they would be ignored)."""
    mode = _input_mode(args)
    foreign = {"--voxel-size": args.voxel_size is not None and mode != "fusion",
               "--min-frames": args.min_frames is not None and mode != "fusion",
               "--matcher": args.matcher != "auto" and mode != "stereo",
               "--depth-range": args.depth_range is not None and mode != "stereo"}
    given = [flag for flag, wrong in foreign.items() if wrong]
    if given:
        what = {"rgbd": "a single RGB-D frame", "fusion": "fused RGB-D frames", "stereo": "a stereo frame"}[mode]
        raise UserError(f"{', '.join(given)} do(es) not apply to {what}")
    return mode


def _input_mode(args) -> str:
    stereo = {"--left": args.left, "--right": args.right, "--stereo-calib": args.stereo_calib}
    if any(stereo.values()):
        if args.rgb or args.depth or args.poses:
            raise UserError("give an RGB-D capture (--rgb, --depth, --poses) or a stereo frame (--left, --right, "
                            "--stereo-calib), not both")
        missing = [flag for flag, value in stereo.items() if not value]
        if missing:
            raise UserError(f"a stereo frame needs --left, --right and --stereo-calib (missing {', '.join(missing)})")
        rgbd_only = [flag for flag, given in (("--camera", args.camera), ("--preset", args.preset),
                                              ("--depth-scale", args.depth_scale is not None),
                                              ("--depth-format", args.depth_format != "auto")) if given]
        if rgbd_only:
            raise UserError(f"{', '.join(rgbd_only)} do(es) not apply to a stereo frame (the calibration gives "
                            "the camera, stereo matching the depth)")
        return "stereo"
    if not args.rgb or not args.depth:
        raise UserError("give --rgb and --depth (an RGB-D capture; several of each to fuse frames) or --left, "
                        "--right and --stereo-calib (a stereo frame)")
    if len(args.rgb) != len(args.depth):
        raise UserError(f"--rgb has {len(args.rgb)} files but --depth has {len(args.depth)}; give one depth per "
                        "colour image")
    if len(args.rgb) == 1:
        if args.poses:
            raise UserError("--poses needs several frames (--rgb A B ... --depth A B ...)")
        return "rgbd"
    return "fusion"


def _intrinsics_and_scale(args):
    from rgbd2scene.capture.camera import camera_for

    return camera_for(args.camera, args.preset, args.depth_scale)


def _load_captures(args) -> list:
    from rgbd2scene.capture.readers import load_capture

    intr, scale = _intrinsics_and_scale(args)
    return [load_capture(rgb, depth, intr, depth_scale=scale, depth_format=args.depth_format)
            for rgb, depth in zip(args.rgb, args.depth, strict=True)]


def _given_poses(args):
    """Poses of the frames from --poses, relative to the first frame, and their scene.json record."""
    from rgbd2scene.capture.trajectory import associate, read_trajectory, relative_to_first

    try:
        trajectory = read_trajectory(args.poses)
        match = associate(trajectory, args.rgb)
    except FileNotFoundError:
        raise UserError(f"{args.poses}: trajectory file not found") from None
    except (OSError, ValueError) as exc:
        raise UserError(f"{args.poses}: {exc}") from None
    record = {"source": "given", "file": args.poses, "format": trajectory.fmt, "association": match.rule,
              "trajectory_indices": match.indices.tolist(), "max_time_difference_s": match.max_time_difference_s,
              "note": "re-expressed so that the first frame's camera frame is the world frame"}
    return relative_to_first(match.poses), record


def _reconstruct(args):
    """The reconstruction of the capture arguments: one RGB-D frame, several fused, or a stereo frame."""
    from rgbd2scene.reconstruct.pipeline import reconstruct

    mode = _check_inputs(args)
    options = _mesh_options(args, mode)
    if mode == "stereo":
        from rgbd2scene.capture.stereo import StereoOptions, load_stereo_capture

        stereo = StereoOptions(matcher=args.matcher)
        if args.depth_range:
            stereo.min_depth, stereo.max_depth = args.depth_range
        try:
            stereo.check()
        except ValueError as exc:
            raise UserError(f"--depth-range/--matcher: {exc}") from None
        return reconstruct(load_stereo_capture(args.left, args.right, args.stereo_calib, stereo), options)
    captures = _load_captures(args)
    if mode == "rgbd":
        return reconstruct(captures[0], options)
    from rgbd2scene.reconstruct.fusion import FusionOptions, reconstruct_fused

    if args.voxel_size is not None and not args.voxel_size > 0:
        raise UserError(f"--voxel-size: must be a positive number of metres, got {args.voxel_size}")
    poses, record = _given_poses(args) if args.poses else (None, None)
    fusion = FusionOptions(voxel_size=args.voxel_size)
    if args.min_frames is not None:
        if args.min_frames < 1:
            raise UserError(f"--min-frames: must be at least 1, got {args.min_frames}")
        fusion.min_frames = args.min_frames
    try:
        return reconstruct_fused(captures, poses, options, fusion, poses_record=record)
    except ValueError as exc:
        raise UserError(f"fusion: {exc}") from None


def _report(recon) -> str:
    """What the mesh command prints about a reconstruction (stage times, then mode-specific figures)."""
    t = recon.timings
    fusion = recon.sections.get("fusion")
    if fusion:
        worst = max(fusion["agreement"], key=lambda row: row["median_mm"])
        return (f"fused {len(fusion['frames'])} frames (poses {fusion['poses']['source']}): poses {t['poses_s']:.3f}s, "
                f"fuse {t['fuse_s']:.3f}s, compute {t['compute_s']:.3f}s, write {t['write_s']:.3f}s; agreement with "
                f"each frame's depth: median abs error <= {worst['median_mm']:.1f} mm (frame {worst['frame']})")
    text = (f"fill {t['fill_s']:.3f}s ({recon.filled.method}), mesh {t['mesh_s']:.3f}s, "
            f"smooth {t['smooth_s']:.3f}s, compute {t['compute_s']:.3f}s, write {t['write_s']:.3f}s")
    stereo = recon.capture.info.get("stereo")
    if stereo:
        st = stereo["stats"]
        pct = st["depth_percentiles_m"]
        text = (f"stereo ({st['matcher']}) {st['seconds']:.3f}s: confident depth on {100 * st['coverage']:.1f} % of "
                f"the image, depth {1e3 * pct['5']:.1f}-{1e3 * pct['95']:.1f} mm (5-95 %)\n{text}")
    return text


def _mesh_options(args, mode: str):
    """MeshOptions from the flags; fill and smoothing default to none when fusing frames (the other frames
    fill each frame's holes, and TSDF fusion averages the noise)."""
    from dataclasses import replace

    from rgbd2scene.options import from_args
    from rgbd2scene.reconstruct.pipeline import MeshOptions

    options = from_args(MeshOptions, args)
    fusion = mode == "fusion"
    return replace(options, fill=options.fill or ("none" if fusion else "auto"),
                   smooth=options.smooth or ("none" if fusion else "ray"), sensor=_sensor_name(args, mode))


def _sensor_name(args, mode: str) -> str:
    """--sensor, else the preset's sensor (the default preset's with --camera); none for a stereo frame (its
    depth comes from matching two images, not from a projector)."""
    from rgbd2scene.capture.camera import PRESET_SENSOR

    if args.sensor:
        return args.sensor
    if mode == "stereo":
        return "none"
    return PRESET_SENSOR.get((args.preset or "primesense").lower(), "kinect_v1")


def cmd_mesh(args) -> int:
    from rgbd2scene.files.atomic import ensure_output_dir
    from rgbd2scene.stages.mesh import write_mesh_folder

    t0 = time.perf_counter()
    ensure_output_dir(args.output)
    recon = _reconstruct(args)
    write_mesh_folder(args.output, recon)
    print(f"{_report(recon)}, total {time.perf_counter() - t0:.2f}s")
    print(f"{len(recon.mesh.vertices)} vertices, {len(recon.mesh.triangles)} triangles -> {args.output}/mesh.ply")
    return 0


def _add_scene_args(p: argparse.ArgumentParser) -> None:
    from rgbd2scene.options import add_arguments
    from rgbd2scene.stages.scene import SceneOptions

    g = p.add_argument_group("scene")
    g.add_argument("--mesh-dir", help="build from a folder made by 'rgbd2scene mesh' instead of a capture")
    add_arguments(g, SceneOptions)


def cmd_scene(args) -> int:
    from rgbd2scene.files.atomic import ensure_output_dir
    from rgbd2scene.options import from_args
    from rgbd2scene.stages.mesh import scene_record, write_mesh_folder
    from rgbd2scene.stages.scene import SceneOptions, build_scene_folder, load_mesh_folder, scene_config

    t0 = time.perf_counter()
    options = from_args(SceneOptions, args)
    config = scene_config(options)  # a bad configuration fails before the reconstruction
    out = ensure_output_dir(args.output)
    if args.mesh_dir:
        mesh, record = load_mesh_folder(args.mesh_dir, out)
    elif _has_capture_input(args):
        recon = _reconstruct(args)
        write_mesh_folder(out, recon, finalize=False)
        mesh, record = recon.mesh, scene_record(recon)
    else:
        raise UserError("scene: give a capture (--rgb and --depth, or --left, --right and --stereo-calib) or "
                        "--mesh-dir (a mesh folder)")
    record = build_scene_folder(out, mesh, record, options, config=config)
    cov = record["coverage"]
    print(f"scene: {record['scene']['path']['frames']} frames ({record['scene']['path']['kind']}), coverage min "
          f"{100 * cov['min']:.1f} % mean {100 * cov['mean']:.1f} %, {time.perf_counter() - t0:.1f}s -> "
          f"{out}/scene.blend")
    for item in record.get("objects", {}).get("instruments", []):
        print(f"instrument {item['name']!r} (ids {item['ids'][0]}-{item['ids'][-1]}): tip in both views in "
              f"{100 * item['in_view_fraction']:.0f} % of the frames, closest to the tissue "
              f"{1e3 * item['clearance_min_m']:.1f} mm")
    return 0


def cmd_render(args) -> int:
    from rgbd2scene.options import from_args
    from rgbd2scene.stages.render import RenderOptions, render_dataset

    summary = render_dataset(args.scene, args.output, from_args(RenderOptions, args), progress=not args.quiet)
    print(f"rendered {summary['rendered']} frames, skipped {summary['skipped']} already done -> {args.output}")
    if not args.no_sheet and not args.gt_only:  # --gt-only renders no images to show
        from rgbd2scene.pictures.contact_sheet import write_frame_sheet

        start, end = summary["range"]
        sheet = write_frame_sheet(args.output, (start + end - 1) // 2, Path(args.output) / "contact_sheet.png")
        print(f"contact sheet: {sheet}")
    return 0


def cmd_verify(args) -> int:
    from rgbd2scene.verify import format_report, verify_dataset

    report = verify_dataset(args.dataset, mesh_path=args.mesh, progress=not args.quiet, error_maps=args.error_maps,
                            blender_frames=args.blender_frames)
    print(format_report(report))
    if args.json:
        from rgbd2scene.files.atomic import write_json

        write_json(args.json, report.to_dict())
    return 0 if report.ok else 1


def cmd_preview(args) -> int:
    from rgbd2scene.pictures.preview import preview

    out = preview(args.mesh, screenshot=args.screenshot, width=args.width, height=args.height)
    if out:
        print(f"screenshot: {out}")
    return 0


def cmd_export_ros(args) -> int:
    from rgbd2scene.dataset import Dataset
    from rgbd2scene.export import RosOptions, export_ros

    try:
        options = RosOptions(version=args.ros, rate=args.rate, start=args.start, prefix=args.prefix,
                             world=args.world_frame, scope=args.scope_frame)
    except ValueError as exc:
        raise UserError(f"export-ros: {exc} (--ros, --rate, --start)") from None
    summary = export_ros(Dataset(args.dataset), args.output, options, progress=not args.quiet)
    print(f"ROS {args.ros} bag: {'; '.join(summary.notes)} -> {summary.out}")
    return 0


def cmd_export(args) -> int:
    from rgbd2scene.dataset import Dataset
    from rgbd2scene.export import FORMATS
    from rgbd2scene.files.atomic import ensure_output_dir

    dataset = Dataset(args.dataset)
    out = ensure_output_dir(args.output)
    summary = FORMATS[args.format](dataset, out, progress=not args.quiet)
    print(f"{args.format}: {summary.frames} frames, {summary.files} files -> {out}")
    for note in summary.notes:
        print(f"note: {note}")
    return 0


def cmd_evaluate(args) -> int:
    from rgbd2scene.evaluate import EvaluationOptions, evaluate
    from rgbd2scene.evaluate.report import markdown_table

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip() and m.strip() != "none")
    if not methods and not args.predictions:
        raise UserError("evaluate: nothing to score (give --methods or --predictions)")
    depth_range = None
    if (args.min_depth is None) != (args.max_depth is None):
        raise UserError("evaluate: give both --min-depth and --max-depth, or neither")
    if args.min_depth is not None:
        if not 0 < args.min_depth < args.max_depth:
            raise UserError(f"evaluate: --min-depth {args.min_depth} and --max-depth {args.max_depth} must satisfy "
                            f"0 < min < max (metres)")
        depth_range = (args.min_depth, args.max_depth)
    options = EvaluationOptions(methods=methods, predictions=tuple(args.predictions or ()), depth_range=depth_range,
                                error_maps=not args.no_error_maps)
    result = evaluate(args.dataset, args.output, options, progress=not args.quiet)
    for split in dict.fromkeys(r.split for r in result.rows):
        print(f"\nsplit {split}: every valid ground-truth pixel (invalid predictions filled)")
        print(markdown_table([r for r in result.rows if r.split == split and r.scored == "all"]))
    print(f"\nmetrics.csv, metrics.md, per_frame.csv{', error_maps/' if options.error_maps else ''} -> {result.out}")
    return 0


def cmd_dataset(args) -> int:
    if args.status is not None:
        if args.config or args.output:
            raise UserError("dataset --status ROOT: give only the build folder (no CONFIG, no -o)")
        from rgbd2scene.batch.status import status_report

        print(status_report(args.status))
        return 0
    if not args.config or not args.output:
        raise UserError("dataset: give CONFIG and -o ROOT (or --status ROOT)")
    from rgbd2scene.batch.run import BuildOptions, build_dataset

    options = BuildOptions(workers=args.workers, scheduler=args.scheduler, jobs=args.jobs,
                           retry_failed=args.retry_failed, dashboard=args.dashboard, progress=not args.quiet)
    summary = build_dataset(args.config, args.output, options)
    print(f"{summary.count('done')} done, {summary.count('failed')} failed, {summary.count('pending')} pending; "
          f"{summary.frames_rendered} frames rendered in {summary.seconds:.0f} s ({summary.engine}) -> "
          f"{summary.root}/manifest.csv, {summary.root}/index.html")
    if summary.failed:
        first = summary.failed[0]
        print(f"error: {len(summary.failed)} sequence(s) failed, first {first.sequence}: {first.error} "
              f"(see {summary.root}/logs/; rerun with --retry-failed)", file=sys.stderr)
        return 1
    return 0


def _args_mesh(p: argparse.ArgumentParser) -> None:
    _add_capture_args(p)
    p.add_argument("-o", "--output", required=True, help="output folder")


def _args_scene(p: argparse.ArgumentParser) -> None:
    _add_capture_args(p)
    _add_scene_args(p)
    p.add_argument("-o", "--output", required=True, help="scene folder")


def _args_render(p: argparse.ArgumentParser) -> None:
    from rgbd2scene.options import add_arguments
    from rgbd2scene.stages.render import RenderOptions

    p.add_argument("scene", help="scene folder made by 'rgbd2scene scene'")
    p.add_argument("-o", "--output", required=True, help="dataset folder")
    add_arguments(p, RenderOptions)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-sheet", action="store_true", help="skip DATASET/contact_sheet.png (middle frame, all maps)")


def _args_dataset(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="configuration file (.yaml, .yml or .toml; see README)")
    p.add_argument("-o", "--output", metavar="ROOT", help="build folder: one dataset folder per sequence, "
                   "manifest.csv, index.html")
    p.add_argument("--status", metavar="ROOT", help="summarise the build in ROOT (in progress or done) and exit")
    p.add_argument("--workers", type=int, metavar="N", help="start a local Dask cluster of N worker processes")
    p.add_argument("--scheduler", metavar="ADDRESS", help="submit to an existing Dask scheduler (tcp://host:8786); "
                   "its workers must see ROOT and the captures at the same paths")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="units run at once by the local pool "
                   "(without --workers or --scheduler; default 1)")
    p.add_argument("--retry-failed", action="store_true", help="also redo the sequences that failed before")
    p.add_argument("--dashboard", action="store_true", help="serve the Dask dashboard (local cluster: port 8787)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or per-sequence lines")


def _args_verify(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder")
    p.add_argument("--mesh", help="scene mesh to ray cast (default: the one dataset.json names)")
    p.add_argument("--json", help="also write the report as JSON")
    p.add_argument("--error-maps", help="folder for error-map pictures of the worst frames (per eye)")
    p.add_argument("--blender-frames", type=int, default=0, metavar="N", help="render N sampled frames' passes "
                   "with Blender and compare the maps with them (the independent second source)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _args_preview(p: argparse.ArgumentParser) -> None:
    p.add_argument("mesh", help="mesh (PLY/OBJ) or scene folder")
    p.add_argument("--screenshot", help="write a PNG instead of opening a window")
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--height", type=int, default=768)


def _args_export_ros(p: argparse.ArgumentParser) -> None:
    from rgbd2scene.export.ros import DEFAULT_START_S

    p.add_argument("dataset", help="dataset folder")
    p.add_argument("-o", "--output", required=True, help="bag: a .bag file (--ros 1) or a bag folder (--ros 2)")
    p.add_argument("--ros", type=int, default=2, choices=(1, 2),
                   help="ROS version: 1 (.bag) or 2 (rosbag2, MCAP storage; default)")
    p.add_argument("--rate", type=float, help="playback rate in Hz: stamps are start + i/rate (default the "
                   "dataset's fps)")
    p.add_argument("--start", type=float, default=DEFAULT_START_S, help="first stamp, seconds since the Unix "
                   f"epoch (default {DEFAULT_START_S}: 2024-01-01, so bags are reproducible)")
    p.add_argument("--prefix", default="/stereo", help="topic prefix (default /stereo: /stereo/left/image_rect_color, "
                   "...)")
    p.add_argument("--world-frame", default="world", help="fixed frame id (default world)")
    p.add_argument("--scope-frame", default="endoscope", help="endoscope frame id; the eyes are "
                   "<scope>_left_optical_frame and <scope>_right_optical_frame (default endoscope)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _args_export(p: argparse.ArgumentParser) -> None:
    from rgbd2scene.export import FORMATS

    p.add_argument("dataset", help="dataset folder")
    p.add_argument("--format", required=True, choices=sorted(FORMATS), help="output layout")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _args_evaluate(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder, or a batch root with manifest.csv (one table per split)")
    p.add_argument("-o", "--output", help="output folder (default DATASET/evaluation)")
    p.add_argument("--methods", default="sgbm,elas", help="comma list of sgbm, elas, gt (the ground truth itself, "
                   "a sanity row), or none (default sgbm,elas)")
    p.add_argument("--predictions", action="append", metavar="[NAME=]DIR",
                   help="score an external method: DIR holds NNNNNN.npy (float32 left disparity, pixels) or "
                   "NNNNNN.pfm per frame (for a batch root, DIR/<sequence>/...); repeatable")
    p.add_argument("--min-depth", type=float, help="nearest depth to search, metres (default: the ground truth's, "
                   "less 10 %%)")
    p.add_argument("--max-depth", type=float, help="farthest depth to search, metres (default: the ground truth's, "
                   "plus 10 %%)")
    p.add_argument("--no-error-maps", action="store_true", help="skip the best/worst frame pictures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


#: command -> (help, the function adding its arguments, the function running it)
COMMANDS = {
    "mesh": ("fill holes, back-project and smooth: OUT/mesh.ply and OUT/scene.json", _args_mesh, cmd_mesh),
    "scene": ("the mesh plus a Blender scene with a stereo endoscope on a path", _args_scene, cmd_scene),
    "render": ("render the stereo dataset with ground truth (resumable)", _args_render, cmd_render),
    "dataset": ("batch build: many captures, sequences and variations from one YAML/TOML configuration "
                "(resumable; local pool or Dask)", _args_dataset, cmd_dataset),
    "verify": ("check the ground truth of a dataset; non-zero exit when it fails", _args_verify, cmd_verify),
    "preview": ("Open3D viewer of a mesh or scene; --screenshot renders headless", _args_preview, cmd_preview),
    "export-ros": ("ROS 1 .bag or ROS 2 (MCAP) bag of the dataset for replay at a chosen rate", _args_export_ros,
                   cmd_export_ros),
    "export": ("the dataset in a standard layout: KITTI, SceneFlow or VisionBlender npz", _args_export, cmd_export),
    "evaluate": ("stereo benchmark: SGBM, ELAS and external predictions scored against the ground truth",
                 _args_evaluate, cmd_evaluate),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The CLI; with ``command``, only that command's arguments are declared (the others' imports take a
    few tenths of a second at every start)."""
    parser = _Parser(prog="rgbd2scene", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (help_text, add_args, run) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text)
        if command in (None, name):
            add_args(p)
        p.set_defaults(func=run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv[0] if argv and argv[0] in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RenderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
