"""Batch dataset builds (``rgbd2scene dataset CONFIG -o ROOT``, CONVENTIONS §8).

One configuration (:mod:`~rgbd2scene.batch.config`) expands deterministically into sequences
(:mod:`~rgbd2scene.batch.plan`); the driver (:mod:`~rgbd2scene.batch.run`) reconstructs each capture once,
builds each sequence's scene and renders its frames in chunks, each a unit of work (:mod:`~rgbd2scene.batch.tasks`)
that a local pool or a Dask cluster runs (:mod:`~rgbd2scene.batch.engine`). ``ROOT/manifest.csv``
(:mod:`~rgbd2scene.batch.manifest`) records every sequence; ``--status`` (:mod:`~rgbd2scene.batch.status`) and
``ROOT/index.html`` (:mod:`~rgbd2scene.batch.gallery`) summarise a build.

Modules are imported where used: importing this package loads nothing heavy.
"""
