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
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 512x256, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def _add_capture_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    from rgbd2scene.reconstruct.texture import HIGHLIGHT_MODES

    g = p.add_argument_group("capture")
    g.add_argument("--rgb", required=required, help="colour image (PNG, JPEG, PPM, BMP)")
    g.add_argument("--depth", required=required, help="depth: 16-bit PNG, float EXR/.npy (m), NYU raw PGM, SUN PNG")
    cam = g.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera JSON: {width,height,fx,fy,cx,cy} or Open3D intrinsic_matrix")
    cam.add_argument("--preset", help="named camera: primesense (default), kinect_v1, tum_fr1, tum_fr2, tum_fr3")
    g.add_argument("--depth-scale", type=float, help="depth units per metre (1000 for mm PNG, 5000 for TUM)")
    g.add_argument("--depth-format", default="auto", help="auto, png, sun, nyu, exr, npy")
    m = p.add_argument_group("reconstruction")
    m.add_argument("--fill", default="auto", help="hole filling: auto, inpaint, colorization, biharmonic, "
                   "background, none (default auto)")
    m.add_argument("--max-jump", type=float, default=0.03,
                   help="drop triangles whose relative depth jump exceeds this (default 0.03)")
    m.add_argument("--max-grazing", type=float, default=85.0,
                   help="drop triangles seen more obliquely than this many degrees (default 85)")
    m.add_argument("--smooth", default="ray", help="smoothing: ray (keeps texture registered), taubin, "
                   "corrective, none (default ray)")
    m.add_argument("--smooth-iterations", type=int, default=10, help="smoothing strength (default 10)")
    m.add_argument("--highlights", default="remove", choices=HIGHLIGHT_MODES,
                   help="specular highlights of the capture image: remove them from the texture (filled from "
                   "the surrounding colour; the image as captured is kept as texture_original.png) or keep "
                   "them (default remove)")
    m.add_argument("--no-overview", action="store_true", help="skip overview.png")


def _load_capture(args):
    from rgbd2scene.capture.camera import PRESET_DEPTH_SCALE, load_camera_json, preset
    from rgbd2scene.capture.readers import load_capture

    scale = args.depth_scale
    if args.camera:
        intr, json_scale = load_camera_json(args.camera)
        scale = scale if scale is not None else json_scale
    else:
        name = args.preset or "primesense"
        intr = preset(name)
        if scale is None and args.preset:
            scale = PRESET_DEPTH_SCALE.get(name.lower())
    return load_capture(args.rgb, args.depth, intr, depth_scale=scale, depth_format=args.depth_format)


def _mesh_options(args):
    from rgbd2scene.reconstruct.pipeline import MeshOptions

    return MeshOptions(fill=args.fill, max_relative_jump=args.max_jump, max_grazing_deg=args.max_grazing,
                       smooth=args.smooth, smooth_iterations=args.smooth_iterations,
                       highlights=args.highlights, overview=not args.no_overview)


def cmd_mesh(args) -> int:
    from rgbd2scene.files.atomic import ensure_output_dir
    from rgbd2scene.reconstruct.pipeline import reconstruct
    from rgbd2scene.stages.mesh import write_mesh_folder

    t0 = time.perf_counter()
    ensure_output_dir(args.output)
    capture = _load_capture(args)
    recon = reconstruct(capture, _mesh_options(args))
    write_mesh_folder(args.output, recon)
    t = recon.timings
    print(f"fill {t['fill_s']:.3f}s ({recon.filled.method}), mesh {t['mesh_s']:.3f}s, "
          f"smooth {t['smooth_s']:.3f}s, compute {t['compute_s']:.3f}s, write {t['write_s']:.3f}s, "
          f"total {time.perf_counter() - t0:.2f}s")
    print(f"{len(recon.mesh.vertices)} vertices, {len(recon.mesh.triangles)} triangles -> {args.output}/mesh.ply")
    return 0


def _add_scene_args(p: argparse.ArgumentParser) -> None:
    from rgbd2scene.scene.model import MATERIALS
    from rgbd2scene.scene.path import PATH_KINDS
    from rgbd2scene.stages.scene import SceneOptions

    d = SceneOptions()  # the defaults shown in --help
    g = p.add_argument_group("scene")
    g.add_argument("--mesh-dir", help="build from a folder made by 'rgbd2scene mesh' instead of --rgb/--depth")
    g.add_argument("--size", type=parse_size, default=d.size, help="endoscope image size WxH (default 512x256)")
    g.add_argument("--fov", type=float, default=d.fov_x_deg, help="horizontal field of view, degrees (default 70)")
    g.add_argument("--scope-camera", help="endoscope intrinsics as a camera JSON (fx, fy, cx, cy, width, height); "
                   "overrides --size and --fov")
    g.add_argument("--baseline", type=float, default=d.baseline, help="stereo baseline, metres (default 0.005)")
    g.add_argument("--path", default=d.path, choices=[k for k in PATH_KINDS if k != "waypoints"],
                   help="generated camera path (default scan)")
    g.add_argument("--path-file", help="JSON path file of waypoints (overrides --path)")
    g.add_argument("--frames", type=int, default=d.frames, help="frames in the path (default 60)")
    g.add_argument("--fps", type=float, default=d.fps, help="frames per second (default 30)")
    g.add_argument("--standoff", type=float, default=d.standoff, help="distance to the tissue, metres (default 0.04)")
    g.add_argument("--seed", type=int, default=d.seed, help="seed of generated paths and of the tissue detail "
                   "(default 0)")
    g.add_argument("--material", default=d.material, choices=MATERIALS, help="tissue look (default wet_tissue)")
    g.add_argument("--tissue-detail", default="on" if d.tissue_detail.enabled else "off", choices=("on", "off"),
                   help="procedural sub-millimetre micro-structure of the wet_tissue material (albedo mottling, "
                   "small vessels, bumps; seeded by --seed; shading only, the ground truth does not change) "
                   "(default on)")
    g.add_argument("--light", default=d.light, choices=("spot", "point"), help="light at the tip (default spot)")
    g.add_argument("--light-power", type=float, default=d.light_power_w, help="light power, watts (default 0.05)")


def cmd_scene(args) -> int:
    from rgbd2scene.capture.camera import load_camera_json
    from rgbd2scene.files.atomic import ensure_output_dir
    from rgbd2scene.reconstruct.pipeline import reconstruct
    from rgbd2scene.scene.materials import TissueDetail
    from rgbd2scene.stages.mesh import scene_record, write_mesh_folder
    from rgbd2scene.stages.scene import SceneOptions, build_scene_folder, load_mesh_folder

    t0 = time.perf_counter()
    out = ensure_output_dir(args.output)
    scope = load_camera_json(args.scope_camera)[0] if args.scope_camera else None
    options = SceneOptions(size=args.size, fov_x_deg=args.fov, intrinsics=scope, baseline=args.baseline, path=args.path,
                           path_file=args.path_file, frames=args.frames, fps=args.fps, standoff=args.standoff,
                           seed=args.seed, material=args.material,
                           tissue_detail=TissueDetail(enabled=args.tissue_detail == "on", seed=args.seed),
                           light=args.light, light_power_w=args.light_power)
    if args.mesh_dir:
        mesh, record = load_mesh_folder(args.mesh_dir, out)
    elif args.rgb and args.depth:
        recon = reconstruct(_load_capture(args), _mesh_options(args))
        write_mesh_folder(out, recon, finalize=False)
        mesh, record = recon.mesh, scene_record(recon)
    else:
        raise UserError("scene: give --rgb and --depth (a capture) or --mesh-dir (a mesh folder)")
    record = build_scene_folder(out, mesh, record, options)
    cov = record["coverage"]
    print(f"scene: {record['scene']['path']['frames']} frames ({options.path}), coverage min "
          f"{100 * cov['min']:.1f} % mean {100 * cov['mean']:.1f} %, {time.perf_counter() - t0:.1f}s -> "
          f"{out}/scene.blend")
    return 0


def cmd_render(args) -> int:
    from rgbd2scene.stages.render import render_dataset

    summary = render_dataset(args.scene, args.output, frames=args.frames, size=args.size, gt=args.gt,
                             start=args.start, end=args.end, samples=args.samples,
                             adaptive=not args.no_adaptive, denoise=args.denoise, device=args.device,
                             chunk=args.chunk, seed=args.seed, threads=args.threads, progress=not args.quiet)
    print(f"rendered {summary['rendered']} frames, skipped {summary['skipped']} already done -> {args.output}")
    if not args.no_sheet:
        from rgbd2scene.pictures.contact_sheet import write_frame_sheet

        start, end = summary["range"]
        sheet = write_frame_sheet(args.output, (start + end - 1) // 2, Path(args.output) / "contact_sheet.png")
        print(f"contact sheet: {sheet}")
    return 0


def cmd_verify(args) -> int:
    from rgbd2scene.verify.driver import format_report, verify_dataset

    report = verify_dataset(args.dataset, mesh_path=args.mesh, progress=not args.quiet, error_maps=args.error_maps)
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


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="rgbd2scene", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("mesh", help="fill holes, back-project and smooth: OUT/mesh.ply and OUT/scene.json")
    _add_capture_args(p)
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.set_defaults(func=cmd_mesh)

    p = sub.add_parser("scene", help="the mesh plus a Blender scene with a stereo endoscope on a path")
    _add_capture_args(p, required=False)
    _add_scene_args(p)
    p.add_argument("-o", "--output", required=True, help="scene folder")
    p.set_defaults(func=cmd_scene)

    from rgbd2scene.stages.render import DEFAULT_CHUNK, DEFAULT_DENOISE, DEFAULT_SAMPLES

    p = sub.add_parser("render", help="render the stereo dataset with ground truth (resumable)")
    p.add_argument("scene", help="scene folder made by 'rgbd2scene scene'")
    p.add_argument("-o", "--output", required=True, help="dataset folder")
    p.add_argument("--frames", type=int, help="dataset length: the first N frames of the path (default all)")
    p.add_argument("--size", type=parse_size, help="image size WxH (default the scene's; K is rescaled)")
    p.add_argument("--gt", default="all", help="maps: all, none, or a list of depth,disparity,normals,flow,"
                   "segmentation (default all)")
    p.add_argument("--start", type=int, help="first frame of this chunk (default 0)")
    p.add_argument("--end", type=int, help="end (exclusive) of this chunk (default the last frame)")
    p.add_argument("--samples", type=int, default=DEFAULT_SAMPLES, help=f"RGB samples per pixel "
                   f"(default {DEFAULT_SAMPLES})")
    p.add_argument("--no-adaptive", action="store_true", help="turn off adaptive sampling")
    p.add_argument("--denoise", default=DEFAULT_DENOISE, help=f"denoiser: none, oidn, optix (default "
                   f"{DEFAULT_DENOISE}; the ground truth never sees it)")
    p.add_argument("--device", default="CPU", help="CPU or GPU (default CPU)")
    p.add_argument("--threads", type=int, default=0, help="render threads (default all cores)")
    p.add_argument("--chunk", type=int, default=DEFAULT_CHUNK, help=f"frames per worker process "
                   f"(default {DEFAULT_CHUNK})")
    p.add_argument("--seed", type=int, default=0, help="Cycles seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-sheet", action="store_true", help="skip DATASET/contact_sheet.png (middle frame, all maps)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("verify", help="check the ground truth of a dataset; non-zero exit when it fails")
    p.add_argument("dataset", help="dataset folder")
    p.add_argument("--mesh", help="scene mesh to ray cast (default: the one dataset.json names)")
    p.add_argument("--json", help="also write the report as JSON")
    p.add_argument("--error-maps", help="folder for error-map pictures of the worst frames (per eye)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("preview", help="Open3D viewer of a mesh or scene; --screenshot renders headless")
    p.add_argument("mesh", help="mesh (PLY/OBJ) or scene folder")
    p.add_argument("--screenshot", help="write a PNG instead of opening a window")
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--height", type=int, default=768)
    p.set_defaults(func=cmd_preview)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
