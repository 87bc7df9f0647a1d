"""rgbd2scene: RGB-D capture -> textured mesh -> Blender stereo-endoscope scene -> ground-truth dataset.

This package is the numpy core and never imports ``bpy``; everything that touches Blender is in
the sibling package ``render``. Start with :mod:`rgbd2scene.api` (``from rgbd2scene import api``): one call
per command, the command's options as keywords.
"""

__version__ = "0.1.0"
