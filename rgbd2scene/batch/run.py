"""The batch driver (``rgbd2scene dataset CONFIG -o ROOT``): plan, then run every unit of work on an engine.

```
ROOT/config.json        the normalised configuration, written first: a different one is refused
ROOT/manifest.csv       one row per sequence (rgbd2scene.batch.manifest)
ROOT/<sequence>/        one dataset folder per sequence (CONVENTIONS §4), with contact_sheet.png
ROOT/meshes/<capture>/  each capture's mesh folder, reconstructed once
ROOT/scenes/<sequence>/ each sequence's scene folder (its camera path, light, material, ...)
ROOT/logs/<sequence>.log  the full story of each failure
ROOT/index.html, ROOT/gallery/  the static gallery (rgbd2scene.batch.gallery)
```

Units depend on each other: a capture's mesh, then each of its sequences' scenes, then each sequence's chunks
of frames. The driver submits a unit when what it needs is there and keeps going when one fails: the failure
lands in the manifest (``error``: its first line) and the log, and that sequence stops. Everything any unit
writes is written atomically, and a folder counts as finished only by the file written last (``scene.json``
of a mesh or scene folder, both eyes' PNG and npz of a frame), so a build killed at any moment (``kill -9``
included) resumes with the same command: finished frames are kept, the rest are done, and the dead run's
leftovers are swept first. One build at a time holds ``ROOT/.lock``.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from rgbd2scene.batch.config import EXECUTION_KEYS, load_config
from rgbd2scene.batch.engine import check_engine, open_engine
from rgbd2scene.batch.manifest import Row, gt_checksum, read_manifest, rgb_checksum, write_manifest
from rgbd2scene.batch.plan import Plan, SequencePlan, make_plan
from rgbd2scene.batch.tasks import Outcome, build_mesh, build_scene, render_chunk
from rgbd2scene.dataset import layout as ds
from rgbd2scene.dataset.layout import lock_held
from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import ensure_output_dir, sweep_temporaries, write_json
from rgbd2scene.scene.folder import SCENE_JSON
from rgbd2scene.stages.render import RenderJob, prepare_render

CONFIG_JSON = "config.json"
LOCK = ".lock"
MESHES, SCENES, LOGS = "meshes", "scenes", "logs"
CONTACT_SHEET = "contact_sheet.png"
#: Seconds between looks at the frames on disk (the progress bar) and between manifest rewrites.
POLL_S = 1.0
MANIFEST_EVERY_S = 5.0
GALLERY_EVERY_S = 60.0
#: Dask priorities: finish started sequences before starting new ones.
PRIORITY = {"mesh": 0, "scene": 1, "render": 2}


@dataclass
class BuildOptions:
    """How to run a build: ``workers`` starts a local Dask cluster, ``scheduler`` uses an existing one,
    otherwise a local pool of ``jobs`` threads; ``retry_failed`` also redoes the failed sequences; ``progress``
    shows the bar and a line per sequence (and, like ``dashboard``, a first line naming the engine)."""

    workers: int | None = None
    scheduler: str | None = None
    jobs: int = 1
    retry_failed: bool = False
    dashboard: bool = False
    progress: bool = True


@dataclass
class BuildSummary:
    """A build's rows and figures: frames rendered and wall seconds of this run, the summed seconds of its
    units (measured where they ran: the rest of the wall time is the driver's and the engine's), and each
    render chunk's Blender worker peak memory."""

    root: Path
    engine: str
    rows: list[Row]
    frames_rendered: int
    seconds: float
    unit_seconds: float = 0.0
    chunk_peak_rss_mb: list[float] = field(default_factory=list)

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.rows)

    @property
    def failed(self) -> list[Row]:
        return [r for r in self.rows if r.status == "failed"]


# --- ROOT: lock, configuration, leftovers ---------------------------------------------------------------

@contextlib.contextmanager
def root_lock(root: Path):
    """Hold ``ROOT/.lock`` for the build; another build of the same ROOT is refused while it lives."""
    path = root / LOCK
    while True:
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise UserError(f"{root}: another 'rgbd2scene dataset' build is running in this folder") from None
        if path.exists() and os.stat(path).st_ino == os.fstat(fd).st_ino:
            break  # not a lock file a finishing build unlinked while we waited
        os.close(fd)
    try:
        yield
    finally:
        path.unlink(missing_ok=True)
        os.close(fd)


def build_running(root: Path) -> bool:
    """Whether a build holds ``ROOT/.lock`` now."""
    return lock_held(root / LOCK)


def _flatten(value, prefix: str = "") -> dict:
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in _flatten(item, f"{prefix}.{key}" if prefix
                                                                          else key).items()}
    if isinstance(value, list):
        return {k: v for i, item in enumerate(value) for k, v in _flatten(item, f"{prefix}[{i}]").items()}
    return {prefix: value}


def config_diff(old: dict, new: dict) -> list[str]:
    """Key paths whose values differ between two configuration records (``captures[1].split``, ...), leaving
    out the keys that only change how a build runs (:data:`EXECUTION_KEYS`)."""
    a, b = _flatten(old), _flatten(new)
    return sorted(k for k in set(a) | set(b) if a.get(k, ...) != b.get(k, ...) and k not in EXECUTION_KEYS)


def check_config(root: Path, record: dict) -> None:
    """Write ``ROOT/config.json``, or refuse a configuration that differs from the one already there."""
    path = root / CONFIG_JSON
    if not path.is_file():
        if any(root.iterdir()) and not (root / "manifest.csv").is_file():
            names = sorted(p.name for p in root.iterdir() if p.name != LOCK)
            if names:
                raise UserError(f"{root}: not empty and not a batch build ({', '.join(names[:3])}, ...); "
                                "choose an empty or new folder")
        write_json(path, record)
        return
    try:
        old = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not readable JSON ({exc})") from None
    diffs = config_diff(old, record)
    if diffs:
        shown = ", ".join(diffs[:8]) + (f" and {len(diffs) - 8} more" if len(diffs) > 8 else "")
        raise UserError(f"{root}: holds a build of another configuration ({shown} differ); use another output "
                        "folder, or delete this one to start over")
    if old != record:  # only execution keys changed: keep the record current
        write_json(path, record)


def _complete(folder: Path) -> bool:
    """A mesh or scene folder is complete when its scene.json (written last) is there."""
    return (folder / SCENE_JSON).is_file()


def sweep_root(root: Path, plan: Plan) -> None:
    """Remove what killed runs left: atomic writers' temporaries, unfinished mesh and scene folders (rebuilt
    from scratch), and the scratch folders of dead render workers in every sequence."""
    for folder in (root, root / LOGS):
        if folder.is_dir():
            sweep_temporaries(folder)
    for parent in (root / MESHES, root / SCENES):
        for folder in (parent.iterdir() if parent.is_dir() else ()):
            if folder.is_dir() and not _complete(folder):
                shutil.rmtree(folder)
            elif folder.is_dir():
                sweep_temporaries(folder)
    for seq in plan.sequences:
        if (root / seq.name).is_dir():
            ds.sweep_dead_runs(root / seq.name)
            sweep_temporaries(root / seq.name)


# --- rows ------------------------------------------------------------------------------------------------

def _frames_done(root: Path, seq: SequencePlan, with_gt: bool) -> int:
    folder = root / seq.name
    if not (folder / ds.DATASET_JSON).is_file():
        return 0
    return sum(ds.frame_done(folder, i, gt=with_gt) for i in range(seq.frames))


def merge_rows(plan: Plan, old: list[Row], root: Path, retry_failed: bool) -> dict[str, Row]:
    """The manifest rows of ``plan``: a ``done`` row stays done when its frames are all there, a ``failed``
    one stays failed unless ``retry_failed``; everything else is pending, with the frames already on disk."""
    previous = {r.sequence: r for r in old}
    with_gt = bool(plan.config.render.maps)
    rows = {}
    for seq in plan.sequences:
        before = previous.get(seq.name)
        row = Row(seq.name, seq.capture.name, seq.split, seq.seed, seq.path, seq.frames, settings=dict(seq.sampled))
        if before is not None:
            row.seconds, row.error = before.seconds, before.error
            row.gt_sha256, row.rgb_sha256 = before.gt_sha256, before.rgb_sha256
            row.status = before.status
        row.frames_done = _frames_done(root, seq, with_gt)
        if row.status == "done" and row.frames_done < seq.frames:
            row.status = "pending"
        if row.status == "failed" and retry_failed:
            row.status = "pending"
        if row.status == "pending":
            row.error, row.gt_sha256, row.rgb_sha256 = "", "", ""
        rows[seq.name] = row
    return rows


# --- the driver ------------------------------------------------------------------------------------------

class _Driver:
    """Submits the units whose inputs are ready, follows their futures and the frames on disk."""

    def __init__(self, plan: Plan, root: Path, engine, rows: dict[str, Row], progress: bool):
        self.plan, self.root, self.engine, self.rows = plan, root, engine, rows
        self.render = plan.config.render
        self.pending: dict = {}  # future -> (stage, name, payload)
        self.jobs: dict[str, RenderJob] = {}
        self.chunks: dict[str, set] = {}
        self.rendered = 0
        self.unit_seconds = 0.0
        self.peaks: list[float] = []
        self.last_manifest = self.last_gallery = time.perf_counter()
        self.t0 = time.perf_counter()
        self.bar = self._bar() if progress else None

    # -- progress --

    def _bar(self):
        from tqdm import tqdm

        live = [r for r in self.rows.values() if r.status != "failed"]
        return tqdm(total=sum(r.frames for r in live), initial=sum(r.frames_done for r in live), unit="frame",
                    desc="dataset", dynamic_ncols=True,
                    bar_format="{l_bar}{bar}| {n}/{total} frames [{elapsed}<{remaining}{postfix}]")

    def say(self, text: str) -> None:
        """A per-sequence line (with the progress bar only: ``--quiet`` prints none)."""
        if self.bar is not None:
            self.bar.write(text)

    def _postfix(self) -> None:
        if self.bar is None:
            return
        counts = {s: sum(r.status == s for r in self.rows.values()) for s in ("done", "failed")}
        hours = (time.perf_counter() - self.t0) / 3600
        rate = f", {self.rendered / hours:.0f} frames/h" if self.rendered and hours > 0 else ""
        self.bar.set_postfix_str(f"sequences {counts['done']}/{len(self.rows)} done, {counts['failed']} failed, "
                                 f"{len(self.jobs)} rendering{rate}", refresh=False)

    def poll_frames(self) -> None:
        """Count the finished frames of the sequences being rendered (whichever engine renders them)."""
        for name, job in self.jobs.items():
            row = self.rows[name]
            done = sum(ds.frame_done(job.out, i, gt=job.with_gt) for i in range(job.frames))
            if done > row.frames_done:
                self.rendered += done - row.frames_done
                if self.bar is not None:
                    self.bar.update(done - row.frames_done)
                row.frames_done = done
        self._postfix()
        if time.perf_counter() - self.last_manifest > MANIFEST_EVERY_S:
            self.write_manifest()

    def write_manifest(self) -> None:
        write_manifest(self.root, list(self.rows.values()))
        self.last_manifest = time.perf_counter()

    # -- units --

    def submit(self, stage: str, name: str, fn, *args, payload=None):
        future = self.engine.submit(fn, *args, key=f"{stage}-{name}", priority=PRIORITY[stage])
        self.pending[future] = (stage, name, payload)
        return future

    def start(self, todo: list[SequencePlan]) -> None:
        by_capture: dict[str, list[SequencePlan]] = {}
        for seq in todo:
            by_capture.setdefault(seq.capture.name, []).append(seq)
        for name, seqs in by_capture.items():
            capture = seqs[0].capture
            mesh_dir = self.root / MESHES / name
            if capture.scene_dir:
                self.mesh_ready(seqs, Path(capture.scene_dir))
            elif _complete(mesh_dir):
                self.mesh_ready(seqs, mesh_dir)
            else:
                self.submit("mesh", name, build_mesh, capture, str(mesh_dir), payload=seqs)

    def mesh_ready(self, seqs: list[SequencePlan], source: Path) -> None:
        for seq in seqs:
            scene_dir = self.root / SCENES / seq.name
            if _complete(scene_dir):
                self.scene_ready(seq)
            else:
                self.submit("scene", seq.name, build_scene, str(source), str(scene_dir), seq.scene, payload=seq)

    def scene_ready(self, seq: SequencePlan) -> None:
        try:
            job = prepare_render(self.root / SCENES / seq.name, self.root / seq.name, seq.render_options(self.render))
        except UserError as exc:
            self.fail(seq, "render", Outcome(False, 0.0, str(exc), str(exc)))
            return
        self.jobs[seq.name] = job
        self.chunks[seq.name] = {self.submit("render", f"{seq.name}-{group[0]:06d}", render_chunk, job, group,
                                             payload=seq) for group in job.chunks()}
        if not self.chunks[seq.name]:
            self.finish(seq)

    def handle(self, future) -> None:
        stage, name, payload = self.pending.pop(future)
        if stage != "mesh" and self.rows[payload.name].status == "failed":
            return  # a unit (perhaps cancelled) of a sequence that failed meanwhile
        try:
            outcome = future.result()
        except Exception as exc:  # noqa: BLE001 - the engine lost the unit (a worker died): that unit failed
            outcome = Outcome(False, 0.0, f"{type(exc).__name__}: {exc}".splitlines()[0], repr(exc))
        self.unit_seconds += outcome.seconds
        if stage == "mesh":
            if outcome.ok:
                self.mesh_ready(payload, self.root / MESHES / name)
            else:
                for seq in payload:
                    self.fail(seq, stage, outcome)
            return
        seq = payload
        row = self.rows[seq.name]
        row.seconds += outcome.seconds
        if not outcome.ok:
            self.fail(seq, stage, outcome)
        elif stage == "scene":
            self.scene_ready(seq)
        else:
            self.peaks.append(outcome.peak_rss_mb)
            self.chunks[seq.name].discard(future)
            if not self.chunks[seq.name]:
                self.finish(seq)

    def finish(self, seq: SequencePlan) -> None:
        """All chunks done: check every frame, checksum the ground truth, write the contact sheet."""
        job = self.jobs.pop(seq.name)
        self.chunks.pop(seq.name, None)
        row = self.rows[seq.name]
        missing = job.incomplete(list(range(job.frames)))
        if missing:
            self.fail(seq, "render", Outcome(False, 0.0, f"frames {missing} of {job.out} are incomplete"))
            return
        from rgbd2scene.pictures.contact_sheet import write_frame_sheet

        try:
            write_frame_sheet(job.out, (job.frames - 1) // 2, job.out / CONTACT_SHEET)
        except (OSError, ValueError, UserError) as exc:
            self.fail(seq, "contact sheet", Outcome(False, 0.0, str(exc), str(exc)))
            return
        if self.bar is not None and row.frames_done < job.frames:
            self.bar.update(job.frames - row.frames_done)
        self.rendered += job.frames - row.frames_done
        row.frames_done = job.frames
        row.gt_sha256 = gt_checksum(job.out, job.frames)
        row.rgb_sha256 = rgb_checksum(job.out, job.frames)
        row.status, row.error = "done", ""
        self.say(f"done    {seq.name} ({seq.split}, {seq.path}, {seq.frames} frames, {row.seconds:.1f} s)")
        self.write_manifest()
        if time.perf_counter() - self.last_gallery > GALLERY_EVERY_S:
            self.write_gallery()

    def write_gallery(self) -> None:
        from rgbd2scene.batch.gallery import write_gallery

        write_gallery(self.root, self.plan, list(self.rows.values()))
        self.last_gallery = time.perf_counter()

    def fail(self, seq: SequencePlan, stage: str, outcome: Outcome) -> None:
        row = self.rows[seq.name]
        if row.status == "failed":
            return
        row.status, row.error = "failed", f"{stage}: {outcome.error}"
        log = self.root / LOGS / f"{seq.name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "a") as f:
            stamp = datetime.datetime.now().isoformat(timespec="seconds")
            f.write(f"{stamp} {stage} failed\n{outcome.log or outcome.error}\n\n")
        self.jobs.pop(seq.name, None)
        for future in self.chunks.pop(seq.name, set()):
            future.cancel()  # the ones not started; handle() skips what comes back
        if self.bar is not None:
            self.bar.total -= row.frames - row.frames_done
        self.say(f"failed  {seq.name} ({seq.split}): {row.error}")
        self.write_manifest()

    def run(self, todo: list[SequencePlan]) -> None:
        self.start(todo)
        try:
            while self.pending:
                self.engine.wait(self.pending, POLL_S)
                for future in [f for f in self.pending if f.done()]:
                    self.handle(future)
                self.poll_frames()
        finally:
            if self.bar is not None:
                self._postfix()
                self.bar.close()
            self.write_manifest()


def build_dataset(config_path: str | Path, root: str | Path, options: BuildOptions | None = None) -> BuildSummary:
    """Build (or resume) the batch of ``config_path`` into ``root``; returns the rows and figures."""
    options = options or BuildOptions()
    check_engine(options.workers, options.scheduler, options.jobs, options.dashboard)
    t0 = time.perf_counter()
    plan = make_plan(load_config(config_path))
    root = ensure_output_dir(root)
    with root_lock(root):
        check_config(root, plan.config.record())
        sweep_root(root, plan)
        rows = merge_rows(plan, read_manifest(root), root, options.retry_failed)
        write_manifest(root, list(rows.values()))
        todo = [s for s in plan.sequences if rows[s.name].status == "pending"]
        engine = open_engine(options.workers, options.scheduler, options.jobs, options.dashboard)
        if options.progress or options.dashboard:  # the dashboard's address even with --quiet
            print(f"{root}: {len(plan.sequences)} sequences ({len(todo)} to do), {plan.frames} frames; "
                  f"{engine.info.describe()}", flush=True)
        driver = _Driver(plan, root, engine, rows, options.progress)
        try:
            driver.run(todo)
        finally:
            engine.close()
        driver.write_gallery()
    return BuildSummary(root, engine.info.describe(), list(rows.values()), driver.rendered,
                        time.perf_counter() - t0, driver.unit_seconds, driver.peaks)
