"""Command line: ``rgbd2scene <command>`` (CONVENTIONS §5).

User errors print one line ``error: ...`` on stderr and exit with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import atexit
import gc
import sys
import time

from rgbd2scene.errors import RenderError, UserError
from rgbd2scene.options import OptionError


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
    from rgbd2scene.options import add_arguments
    from rgbd2scene.reconstruct.pipeline import MeshOptions
    from rgbd2scene.stages.capture import CaptureOptions

    add_arguments(p, CaptureOptions)
    add_arguments(p.add_argument_group("reconstruction"), MeshOptions)


def _capture_options(args):
    """The capture and reconstruction options of the arguments (``mesh`` and ``scene``)."""
    from rgbd2scene.options import from_args
    from rgbd2scene.reconstruct.pipeline import MeshOptions
    from rgbd2scene.stages.capture import CaptureOptions

    return from_args(CaptureOptions, args), from_args(MeshOptions, args)


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


def cmd_mesh(args) -> int:
    from rgbd2scene.api import run_mesh

    result = run_mesh(args.output, *_capture_options(args))
    recon = result.reconstruction
    print(f"{_report(recon)}, total {result.seconds:.2f}s")
    print(f"{len(recon.mesh.vertices)} vertices, {len(recon.mesh.triangles)} triangles -> {args.output}/mesh.ply")
    return 0


def _add_scene_args(p: argparse.ArgumentParser) -> None:
    from rgbd2scene.options import add_arguments
    from rgbd2scene.stages.scene import SceneOptions

    g = p.add_argument_group("scene")
    g.add_argument("--mesh-dir", help="build from a folder made by 'rgbd2scene mesh' instead of a capture")
    add_arguments(g, SceneOptions)


def cmd_scene(args) -> int:
    from rgbd2scene.api import run_scene
    from rgbd2scene.options import from_args
    from rgbd2scene.stages.scene import SceneOptions

    t0 = time.perf_counter()
    options = from_args(SceneOptions, args)
    result = run_scene(args.output, *_capture_options(args), options, args.mesh_dir)
    record, out = result.record, result.folder
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
    from rgbd2scene.api import run_render
    from rgbd2scene.options import from_args
    from rgbd2scene.stages.render import RenderOptions

    result = run_render(args.scene, args.output, from_args(RenderOptions, args), progress=not args.quiet,
                        sheet=not args.no_sheet)
    print(f"rendered {result.rendered} frames, skipped {result.skipped} already done -> {args.output}")
    if result.sheet is not None:
        print(f"contact sheet: {result.sheet}")
    return 0


def cmd_verify(args) -> int:
    from rgbd2scene import api
    from rgbd2scene.verify import format_report

    report = api.verify(args.dataset, mesh=args.mesh, json=args.json, error_maps=args.error_maps,
                        blender_frames=args.blender_frames, progress=not args.quiet)
    print(format_report(report))
    return 0 if report.ok else 1


def cmd_preview(args) -> int:
    from rgbd2scene.pictures.mesh_preview import preview

    out = preview(args.mesh, screenshot=args.screenshot, width=args.width, height=args.height)
    if out:
        print(f"screenshot: {out}")
    return 0


def cmd_export_ros(args) -> int:
    from rgbd2scene import api

    summary = api.export_ros(args.dataset, args.output, ros=args.ros, rate=args.rate, start=args.start,
                             prefix=args.prefix, world_frame=args.world_frame, scope_frame=args.scope_frame,
                             progress=not args.quiet)
    print(f"ROS {args.ros} bag: {'; '.join(summary.notes)} -> {summary.out}")
    return 0


def cmd_export(args) -> int:
    from rgbd2scene import api

    summary = api.export(args.dataset, args.format, args.output, progress=not args.quiet)
    print(f"{args.format}: {summary.frames} frames, {summary.files} files -> {summary.out}")
    for note in summary.notes:
        print(f"note: {note}")
    return 0


def cmd_evaluate(args) -> int:
    from rgbd2scene import api
    from rgbd2scene.evaluate.report import markdown_table

    result = api.evaluate(args.dataset, args.output, methods=args.methods, predictions=args.predictions or (),
                          min_depth=args.min_depth, max_depth=args.max_depth, error_maps=not args.no_error_maps,
                          progress=not args.quiet)
    for split in dict.fromkeys(r.split for r in result.rows):
        print(f"\nsplit {split}: every valid ground-truth pixel (invalid predictions filled)")
        print(markdown_table([r for r in result.rows if r.split == split and r.scored == "all"]))
    print(f"\nmetrics.csv, metrics.md, per_frame.csv{'' if args.no_error_maps else ', error_maps/'} -> {result.out}")
    return 0


def cmd_realism(args) -> int:
    from rgbd2scene import api
    from rgbd2scene.realism.report import markdown_table, summary_line

    result = api.realism(args.dataset, args.real, args.output, real_disparity=args.real_disparity,
                         real_mask=args.real_mask, real_calib=args.real_calib, surface_only=args.surface_only,
                         frame=args.frame, methods=args.methods)
    print(markdown_table(result.report))
    print(f"\n{summary_line(result.report)}")
    for note in result.report.notes:
        print(f"note: {note}")
    print(f"table: {result.markdown}, {result.json}; picture: {result.picture}")
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
    from rgbd2scene import api

    summary = api.dataset(args.config, args.output, workers=args.workers, scheduler=args.scheduler, jobs=args.jobs,
                          retry_failed=args.retry_failed, dashboard=args.dashboard, progress=not args.quiet)
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
                   "NNNNNN.pfm per frame (for a batch root, DIR/<sequence>/...); a raw dataset's in the rectified grid "
                   "of its calibration.yaml (cv2.stereoRectify, alpha 0), where the built-in methods match too; "
                   "repeatable")
    p.add_argument("--min-depth", type=float, help="nearest depth to search, metres (default: the ground truth's, "
                   "less 10 %%)")
    p.add_argument("--max-depth", type=float, help="farthest depth to search, metres (default: the ground truth's, "
                   "plus 10 %%)")
    p.add_argument("--no-error-maps", action="store_true", help="skip the best/worst frame pictures")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _args_realism(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder (rendered at the real frame's size)")
    p.add_argument("--real", nargs="+", required=True, metavar="IMAGE", help="the real LEFT image, and the RIGHT one "
                   "for the stereo difficulty rows")
    p.add_argument("--real-disparity", metavar="FILE", help="the real pair's left ground-truth disparity (.npy or "
                   ".pfm, pixels; of the rectified pair when --real-calib is given): adds the SGBM and ELAS error rows")
    p.add_argument("--real-mask", metavar="IMAGE", help="the real frames' valid pixels (at least half scale; one "
                   "mask for both eyes); the same pixels are measured in the render")
    p.add_argument("--real-calib", metavar="CALIB", help="stereo calibration of a raw real pair (JSON or Hamlyn "
                   "folder, as --stereo-calib): rectified before matching (default: the dataset's calibration.yaml "
                   "for a raw dataset, else the pair is taken as rectified)")
    p.add_argument("--surface-only", action="store_true", help="measure only the pixels where the rendered frame "
                   "sees a surface (a twin's mesh may not cover the whole view), in both images")
    p.add_argument("--frame", type=int, default=0, help="the rendered frame to compare (default 0)")
    p.add_argument("--methods", default="sgbm,elas", help="stereo methods: comma list of sgbm, elas, or none")
    p.add_argument("-o", "--output", help="output folder (default DATASET/realism)")


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
    "realism": ("how close rendered frames are to real ones: a table render / real and a side-by-side picture",
                _args_realism, cmd_realism),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The CLI; with ``command``, only that command's arguments are declared (the others' imports take a
    few tenths of a second at every start)."""
    from rgbd2scene.options import flags_of

    parser = _Parser(prog="rgbd2scene", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (help_text, add_args, run) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text)
        if command in (None, name):
            add_args(p)
        # a library's OptionError names a field; the command spells it as its flag
        p.set_defaults(func=run, option_flags=flags_of(p))
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command of ``argv`` (default: the process's own arguments) and return its exit status."""
    if argv is None:  # the process's own command (the console script): the interpreter exits after it
        _skip_final_collections()
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv[0] if argv and argv[0] in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OptionError as exc:
        print(f"error: {exc.render(lambda name: args.option_flags.get(name, name))}", file=sys.stderr)
        return 2
    except RenderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


def _skip_final_collections() -> None:
    """Freeze the heap when the interpreter exits (an ``atexit`` handler, so after the command's own exit code).

    The interpreter's last garbage collections traverse every object of NumPy, SciPy and OpenCV: 0.1-0.4 s at
    the end of every command on a 2-core machine, 0.04-0.07 s with them frozen (skipped). Cyclic garbage is then
    not collected, only freed with the process: nothing of ours waits for a collection to be closed (every writer
    closes its own file).
    """
    atexit.register(gc.freeze)


if __name__ == "__main__":
    sys.exit(main())
