"""Per-phase render timings (render/timing.py) from Cycles' status lines, as a worker reports them."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from render.timing import PhaseClock, phase_of
from rgbd2scene.stages.blender import frame_line, parse_line

#: Status lines as Blender 5.0 passes them to ``render_stats`` (recorded from a render of the sample scene).
STATUS = [("Mem: 0M | Synchronizing object | Tissue", "sync"), ("Mem: 0M | Initializing", "sync"),
          ("Mem: 2M | Updating Images | Loading Texture", "sync"),
          ("Mem: 2M | Loading render kernels (may take a few minutes the first time)", "sync"),
          ("Mem: 19M | Updating Geometry BVH Tissue 2/1 | Building BVH", "bvh"),
          ("Mem: 56M | Updating Scene BVH | Copying BVH to device", "bvh"),
          ("Mem: 56M | Updating Mesh | Computing normals", "sync"), ("Mem: 73M | Sample 0/8", "trace"),
          ("Remaining: 00:01.30 | Mem: 76M | Sample 1/8", "trace"), ("Mem: 76M | Finished", "save"),
          ("Time: 00:04.98 (Saving: 00:00.00)", None)]


@pytest.mark.parametrize("status, phase", STATUS)
def test_phase_of_cycles_status(status, phase):
    assert phase_of(status) == phase


class FakeBpy:
    """Just the handler lists :class:`PhaseClock` registers on."""

    def __init__(self):
        names = ("render_init", "render_stats", "render_complete", "render_cancel")
        self.app = SimpleNamespace(handlers=SimpleNamespace(persistent=lambda f: f, **{n: [] for n in names}))

    def fire(self, name: str, *args) -> None:
        for fn in getattr(self.app.handlers, name):
            fn(*args, None)


def _scene(frame: int, override=None):
    return SimpleNamespace(frame_current=frame, view_layers=[SimpleNamespace(material_override=override)])


def test_phase_clock_adds_intervals_per_kind_frame_and_phase():
    bpy, now = FakeBpy(), [0.0]
    clock = PhaseClock(bpy, clock=lambda: now[0])

    def at(t, name, *args):
        now[0] = t
        bpy.fire(name, *args)

    # an RGB render of frame 4, both eyes: sync 1, BVH 2, trace 3 + 1, save 0.5 (the eyes' sync adds up)
    at(0.0, "render_init", _scene(4))
    at(0.5, "render_stats", "Mem: 0M | Synchronizing object | Tissue")
    at(1.0, "render_stats", "Mem: 19M | Updating Geometry BVH Tissue 2/1 | Building BVH")
    at(3.0, "render_stats", "Mem: 73M | Sample 0/1")
    at(6.0, "render_stats", "Mem: 76M | Finished")
    at(6.0, "render_stats", "Mem: 76M | Waiting for render to start")  # the second eye
    at(6.0, "render_stats", "Mem: 76M | Sample 0/1")
    at(7.0, "render_stats", "Mem: 76M | Sample 1/1")
    at(7.0, "render_stats", "Mem: 76M | Finished")
    at(7.2, "render_stats", "Time: 00:07.20 (Saving: 00:00.20)")
    at(7.5, "render_complete", _scene(4))
    at(9.0, "render_stats", "Mem: 76M | Sample 0/1")  # no render running: ignored
    # the data render of frame 4 (a material override) and of frame 5
    at(10.0, "render_init", _scene(4, override=object()))
    at(10.25, "render_stats", "Mem: 76M | Sample 0/1")
    at(10.5, "render_complete", _scene(4))
    at(11.0, "render_init", _scene(5, override=object()))
    at(12.0, "render_cancel", _scene(5))

    assert clock.take("rgb", 4) == pytest.approx({"rgb_sync": 1.0, "rgb_bvh": 2.0, "rgb_trace": 4.0,
                                                  "rgb_save": 0.5})
    assert clock.take("rgb", 4) == {}  # taken once
    assert clock.take("gt", 4) == pytest.approx({"gt_sync": 0.25, "gt_bvh": 0.0, "gt_trace": 0.25, "gt_save": 0.0})
    assert clock.take("gt", 5)["gt_sync"] == pytest.approx(1.0)


def test_phases_travel_on_progress_lines():
    line = frame_line(3, "done", 2.0, cpu=3.9, rgb=1.8, gt=0.2, rss=668) + " rgb_trace 1.250s gt_bvh 0.010s"
    event = parse_line(line)
    assert event.kind == "done" and event.frame == 3
    assert event.stats["rgb_trace"] == 1.25 and event.stats["gt_bvh"] == 0.01 and event.stats["rgb"] == 1.8
