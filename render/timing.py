"""Where a render's time goes, as Cycles reports it (needs ``bpy``): seconds per phase and frame.

Cycles announces each step of a render in its status line (``bpy.app.handlers.render_stats``, once per
change): ``Synchronizing object``, ``Updating Geometry BVH``, ``Sample 3/16``, ``Finished``... A
:class:`PhaseClock` timestamps those changes and adds each interval to the phase it belongs to:

- ``sync``: Blender exporting the scene to Cycles and Cycles updating it (objects, meshes, shaders, images,
  kernels), except the BVH;
- ``bvh``: building the geometry and scene BVHs;
- ``trace``: from the first sample to the last, denoising included (Cycles denoises after the last sample and
  reports no step of its own: the profile benchmark tells the two apart with a render without denoiser);
- ``save``: from ``Finished`` to the end of the render operator (the image files Blender encodes and writes).

Both eyes of a stereo render add to the same phases. Renders are counted per frame (``scene.frame_current``)
and per kind: ``gt`` when the view layer has a material override (the data render of ground truth), else
``rgb``. The worker appends a frame's phases to its progress lines (``frame 3 done ... rgb_trace 1.2s``).
"""

from __future__ import annotations

import time
from collections import defaultdict

PHASES = ("sync", "bvh", "trace", "save")


def phase_of(status: str) -> str | None:
    """The phase of one Cycles status line (``"Mem: 2M | Updating Scene BVH | Building"``), None for a line
    that marks no step (``Time: ...``, the summary after saving)."""
    parts = [p.strip() for p in status.split("|")]
    parts = [p for p in parts if p and not p.startswith(("Mem:", "Remaining:", "Fra:", "Peak:"))]
    if not parts or parts[0].startswith("Time:"):
        return None
    step = parts[0]
    if step.startswith("Sample"):
        return "trace"
    if step.startswith("Finished"):
        return "save"
    if "BVH" in step:
        return "bvh"
    return "sync"


class PhaseClock:
    """Seconds per (kind, frame, phase) of the renders of this process, from Blender's render handlers."""

    def __init__(self, bpy, clock=time.perf_counter):
        self.clock = clock
        self.spent: dict[tuple[str, int], dict[str, float]] = defaultdict(lambda: dict.fromkeys(PHASES, 0.0))
        self._key: tuple[str, int] | None = None
        self._phase: str | None = None
        self._since = 0.0
        handlers = bpy.app.handlers
        # persistent: opening the scene's blend would otherwise drop them
        for handler, method in ((handlers.render_init, self._start), (handlers.render_stats, self._status),
                                (handlers.render_complete, self._stop), (handlers.render_cancel, self._stop)):
            handler.append(handlers.persistent(_function(method)))

    def _switch(self, phase: str | None) -> None:
        now = self.clock()
        if self._key is not None and self._phase is not None:
            self.spent[self._key][self._phase] += now - self._since
        self._phase, self._since = phase, now

    def _start(self, scene, *_) -> None:
        layer = scene.view_layers[0] if len(scene.view_layers) else None
        kind = "gt" if layer is not None and layer.material_override is not None else "rgb"
        self._key = (kind, int(scene.frame_current))
        self._switch("sync")

    def _status(self, status, *_) -> None:
        if self._key is None:
            return
        phase = phase_of(str(status))
        if phase is not None and phase != self._phase:
            self._switch(phase)

    def _stop(self, *_) -> None:
        self._switch(None)
        self._key = None

    def take(self, kind: str, frame: int) -> dict[str, float]:
        """The phases (``<kind>_<phase>`` -> seconds) of the ``kind`` renders of ``frame`` not taken yet."""
        spent = self.spent.pop((kind, frame), None)
        return {} if spent is None else {f"{kind}_{p}": s for p, s in spent.items()}


def _function(method):
    """A plain function calling ``method`` (Blender's ``persistent`` marks functions, not bound methods)."""

    def call(*args):
        method(*args)

    return call
