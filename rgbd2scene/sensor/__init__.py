"""The endoscope camera's sensor model (numpy, no ``bpy``): exposure, vignetting, noise, tone, video chain.

:func:`~rgbd2scene.sensor.pipeline.develop` turns one eye's linear render into the 8-bit image; the auto
exposure (:mod:`~rgbd2scene.sensor.exposure`) sets each frame's light and gain; the estimators
(:mod:`~rgbd2scene.sensor.estimate`) measure real frames. It changes only the RGB images, never the ground truth.
"""

from rgbd2scene.sensor.exposure import Exposure, frame_exposure, meter, smoothed_log_exposure, split_exposure
from rgbd2scene.sensor.pipeline import Developed, develop
from rgbd2scene.sensor.settings import SensorOptions

__all__ = ["Developed", "Exposure", "SensorOptions", "develop", "frame_exposure", "meter", "smoothed_log_exposure",
           "split_exposure"]
