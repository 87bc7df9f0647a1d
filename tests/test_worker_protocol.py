"""The worker's tasks (one payload per action, a handler per payload type) and the render options they carry."""

import json

import pytest

from render.worker import HANDLERS
from rgbd2scene.options import OptionError
from rgbd2scene.rendering import DENOISERS, ENGINES, RenderOptions
from rgbd2scene.worker_protocol import PAYLOADS, TASK_VERSION, BuildScene, Describe, Render, Task


@pytest.mark.parametrize("payload", [BuildScene("/s", {"a": 1}, "/s/scene.blend"), Describe("/s"),
                                     Render("/s", "/d", {"b": 2}, render={"samples": 4}, frames=9, start=3, end=6)])
def test_task_round_trips_its_payload(payload):
    task = Task(payload)
    record = json.loads(task.to_json())
    assert record["action"] == task.action and PAYLOADS[task.action] is type(payload)
    assert Task.from_json(task.to_json()) == task


def test_every_payload_has_a_handler():
    assert set(HANDLERS) == set(PAYLOADS.values())


@pytest.mark.parametrize("record, message", [
    ({"version": TASK_VERSION, "action": "paint", "payload": {}}, "unknown task action 'paint'"),
    ({"version": 1, "action": "describe", "scene_dir": "/s"}, "task version 1"),
])
def test_bad_task_files_are_refused(record, message):
    with pytest.raises(ValueError, match=message):
        Task.from_json(json.dumps(record))


def test_engines_and_prefilters_are_options():
    options = RenderOptions(engine="cycles-gpu", prefilter="accurate", denoise_quality="high").validated()
    assert ENGINES[options.engine].gpu and not ENGINES["cycles"].gpu
    assert DENOISERS[options.denoise].prefilter and not DENOISERS["none"].prefilter
    assert options.denoise_quality == "high" and RenderOptions().denoise_quality == "fast"
    for name, value in (("engine", "eevee"), ("prefilter", "sharp"), ("denoise_quality", "ultra")):
        with pytest.raises(OptionError, match=f"choose one of .*got '{value}'") as caught:
            RenderOptions(**{name: value}).validated()
        assert caught.value.name == name
